"""Message schemas of the leader-following family (Sec. 5.3), in the form of
:mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["PLAN_KIND", "STATUS_KIND", "PAYLOADS"]

PLAN_KIND = "leader_plan"
"""The leader's plan (s_l, sdot_pred, delta_l) sent after each solve (Sec. 5.3.3)."""
STATUS_KIND = "follower_status"
"""A follower's tracking error for the formation feedback (beyond the text)."""

PAYLOADS = {
    # Sec. 5.3: leader broadcast after each solve.
    PLAN_KIND: {"s_l": "float", "sdot_pred": "floats", "delta_l": "float", "slowdown?": "float"},
    # Sec. 5.3 extension (formation feedback): follower -> leader tracking error.
    STATUS_KIND: {"tracking_error": "float"},
}
