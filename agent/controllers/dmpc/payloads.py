"""Message schemas of the dmpc family (Sec. 5.4), in the form of :mod:`copath.wire.payloads`."""

from __future__ import annotations

__all__ = ["MESSAGE_KIND", "PAYLOADS"]

MESSAGE_KIND = "assumed_traj"
"""Kind of the assumed-trajectory message of Algorithm 5.1 (step 2)."""

PAYLOADS = {
    # Sec. 5.4, Algorithm 5.1: assumed trajectory s_hat on the grid t0 + k dt.
    MESSAGE_KIND: {"t0": "float", "dt": "float", "s_hat": "floats", "psi_scale?": "float"},
}
