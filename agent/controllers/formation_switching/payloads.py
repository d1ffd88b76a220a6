"""Message schemas of the formation-switching family (E6.6), in the form of
:mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["MESSAGE_KIND", "PAYLOADS"]

MESSAGE_KIND = "formation_state"
"""Kind of the broadcast of the formation coordinate xi, its rate and the formation index."""

PAYLOADS = {
    # E6.6: coordination coordinate xi = s - s_d, its rate, and the formation index.
    MESSAGE_KIND: {"xi": "float", "xidot": "float", "formation": "int", "index": "int", "xiddot?": "float"},
}
