"""Offset curves (Appendix A, (A.1)-(A.11); (5.4)-(5.5), (5.10)-(5.13)) and quintic
offset transitions (5.1)-(5.3).

An offset point o(s) = r(s) + q(s) n_c(s) lies at lateral distance q to the left of
the progenitor path r. Its arc-length rate is H = sqrt((1 - k_c q)^2 + q'^2) (A.4),
its curvature k_i from (A.5)-(A.10), and its velocities u_i = H u_c, omega_i = k_i u_i
(A.8)-(A.9) = (5.4)-(5.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .paths import Path

__all__ = ["Quintic", "OffsetState", "offset_state", "constant_offset_velocities"]


@dataclass(frozen=True)
class Quintic:
    """Quintic transition of an offset from q_start to q_end over [s_start, s_end], (5.1)-(5.3).

    q(s) = q_start + dq (10 sd^3 - 15 sd^4 + 6 sd^5), sd = clip((s - s_start)/ds, 0, 1);
    value, slope and second derivative match at both ends.
    """

    q_start: float
    q_end: float
    s_start: float
    s_end: float

    def __post_init__(self) -> None:
        if not self.s_end > self.s_start:
            raise ValueError(f"quintic needs s_end > s_start, got {self.s_start} .. {self.s_end}")

    def __call__(self, s):
        """Return (q, q', q'') at s (scalars or arrays)."""
        s = np.asarray(s, dtype=float)
        ds = self.s_end - self.s_start
        dq = self.q_end - self.q_start
        sd = np.clip((s - self.s_start) / ds, 0.0, 1.0)
        inside = (s > self.s_start) & (s < self.s_end)
        q = self.q_start + dq * (10 * sd**3 - 15 * sd**4 + 6 * sd**5)
        dq1 = np.where(inside, dq / ds * (30 * sd**2 - 60 * sd**3 + 30 * sd**4), 0.0)
        dq2 = np.where(inside, dq / ds**2 * (60 * sd - 180 * sd**2 + 120 * sd**3), 0.0)
        return q, dq1, dq2


@dataclass(frozen=True)
class OffsetState:
    """Geometry of an offset curve at one or more path coordinates."""

    pos: np.ndarray
    """(..., 2) offset point o(s)."""
    theta: np.ndarray
    """Heading of the offset curve: theta_p + atan2(q', 1 - k_c q)."""
    H: np.ndarray
    """dl/ds of (A.4)."""
    kappa: np.ndarray
    """Curvature k_i of the offset curve (A.10)."""


def offset_state(path: Path, s, q, dq=0.0, ddq=0.0) -> OffsetState:
    """Offset-curve geometry at s for the lateral offset q(s) with derivatives dq, ddq.

    Uses the smooth form k_i = b / ((1 - k_c q) H) (docs/reference/derivations.md, offset curves (D3)), valid while
    1 - k_c q > 0; raises ValueError at or beyond a cusp.
    """
    s = np.asarray(s, dtype=float)
    q, dq, ddq = (np.broadcast_to(np.asarray(a, dtype=float), s.shape) for a in (q, dq, ddq))
    kc = np.asarray(path.kappa(s))
    dkc = np.asarray(path.dkappa(s))
    th = np.asarray(path.theta(s))
    one = 1.0 - kc * q
    if np.any(one <= 0):
        raise ValueError("offset beyond the path's radius of curvature (1 - k_c q <= 0): cusp")
    H = np.sqrt(one**2 + dq**2)
    G = one * (-kc * dq - q * dkc) + dq * ddq  # (A.5)
    b = kc - kc**2 * q + ddq - dq * G / H**2  # (A.6)
    kappa = b / (one * H)
    n = np.stack([-np.sin(th), np.cos(th)], axis=-1)
    pos = np.asarray(path.pos(s)) + q[..., None] * n
    theta = th + np.arctan2(dq, one)
    return OffsetState(pos=pos, theta=theta, H=H, kappa=kappa)


def constant_offset_velocities(kappa_p, q, u_o):
    """Reference velocities for a constant offset q, (5.11)-(5.13).

    Returns (u_r, omega_r, kappa_i) with u_r = u_o (1 - kappa_p q),
    kappa_i = kappa_p / (1 - q kappa_p), omega_r = kappa_i u_r = kappa_p u_o.
    """
    kappa_p = np.asarray(kappa_p, dtype=float)
    one = 1.0 - kappa_p * q
    u_r = u_o * one
    kappa_i = kappa_p / one
    return u_r, kappa_i * u_r, kappa_i
