"""Message schemas of the heterogeneous family (Sec. 5.5.5), in the form of
:mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["REPORT_KIND", "COMMAND_KIND", "PAYLOADS"]

REPORT_KIND = "hetero_report"
"""A follower's pose estimate sent to the leader (camera fix plus compass heading)."""
COMMAND_KIND = "hetero_cmd"
"""The leader's velocity command for one follower."""

PAYLOADS = {
    # Sec. 5.5.5: leader -> follower velocity command; follower -> leader report.
    # The command carries the follower's reference pose and coordination coordinate
    # computed on the leader (for the follower's telemetry); the report is the follower's
    # pose estimate (the leader's camera fix plus compass heading in the original).
    COMMAND_KIND: {"v": "float", "omega": "float", "ref?": "floats", "xi?": "float"},
    REPORT_KIND: {"x": "float", "y": "float", "heading": "float"},
}
