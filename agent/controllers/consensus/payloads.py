"""Message schemas of the consensus family (Sec. 5.5), in the form of :mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["MESSAGE_KIND", "PAYLOADS"]

MESSAGE_KIND = "coord_state"
"""Kind of the coordination-state broadcast (s_i, sdot_i, s_di) of (5.42)."""

PAYLOADS = {
    # Sec. 5.5: path coordinate and virtual-vehicle speed, (5.42); receivers
    # extrapolate s by sdot times the message age; s_d is the sender's desired
    # offset, so s_dij = s_di - s_dj needs no global table; sddot is the sender's
    # acceleration, for a second-order prediction over the message age.
    MESSAGE_KIND: {"s": "float", "sdot": "float", "s_d": "float", "sddot?": "float"},
}
