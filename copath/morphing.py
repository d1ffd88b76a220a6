"""Morphing between reference paths for coordination on several paths (Sec. 5.4.3, (5.28)-(5.29)).

When robot i follows its own path Gamma_i, progress along different paths is compared
in the coordinates of a base path Gamma_B (one of the paths or a new one). With P(.)
the length of one period of a path (analytically or by quadrature: here the arc length
that :class:`copath.paths.Path` computes by Simpson's rule),

- the desired forward speed of robot i is u_i,d = P(Gamma_i) / P(Gamma_B) u_B,d   (5.28)
- its progress and speed in base coordinates are
  psi_i = P(Gamma_B) / P(Gamma_i) s_i and sigma_i = P(Gamma_B) / P(Gamma_i) u_i,d  (5.29)

so the robots spend the same time on each period when every sigma_i equals sigma_B,
and the coupling term of (5.17) becomes W (psi_i - psi_j + p_ij)^2 with
psi_i + p_ij = psi_j. Pure geometry: numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .paths import Path

__all__ = ["Morphing", "period_length", "desired_speed", "morphing", "configuration"]


def period_length(path: Path) -> float:
    """P(Gamma): the length of one period of a closed path, or the whole open path [m]."""
    return float(path.length)


def desired_speed(own_length: float, base_length: float, base_speed: float) -> float:
    """Desired forward speed on the own path, u_i,d = P(Gamma_i)/P(Gamma_B) u_B,d (5.28)."""
    if own_length <= 0 or base_length <= 0:
        raise ValueError(f"path lengths must be > 0, got own {own_length}, base {base_length}")
    return own_length / base_length * base_speed


@dataclass(frozen=True)
class Morphing:
    """The map between one robot's path coordinate s_i and base coordinates psi_i (5.29).

    Attributes are the two period lengths; a robot on the base path itself has
    ``scale == 1``.
    """

    own_length: float
    """P(Gamma_i) [m]."""
    base_length: float
    """P(Gamma_B) [m]."""

    def __post_init__(self) -> None:
        if not (self.own_length > 0 and self.base_length > 0):
            raise ValueError(
                f"morphing needs positive lengths, got own_length={self.own_length!r}, "
                f"base_length={self.base_length!r}"
            )

    @property
    def scale(self) -> float:
        """d psi / d s = P(Gamma_B) / P(Gamma_i)."""
        return self.base_length / self.own_length

    def psi(self, s):
        """Progress in base coordinates psi_i = P_B / P_i s_i (5.29); arrays welcome."""
        return np.asarray(s, dtype=float) * self.scale if np.ndim(s) else float(s) * self.scale

    def s(self, psi):
        """Own path coordinate of the base coordinate psi (inverse of (5.29))."""
        return np.asarray(psi, dtype=float) / self.scale if np.ndim(psi) else float(psi) / self.scale

    def sigma(self, u):
        """Speed in base coordinates sigma_i = P_B / P_i u (5.29)."""
        return np.asarray(u, dtype=float) * self.scale if np.ndim(u) else float(u) * self.scale

    def desired_speed(self, base_speed: float) -> float:
        """u_i,d for the base speed sigma_B = u_B,d, (5.28)."""
        return desired_speed(self.own_length, self.base_length, base_speed)


def morphing(own: Path, base: Path, own_length: float | None = None) -> Morphing:
    """Morphing of ``own`` onto ``base``.

    ``own_length`` overrides P(Gamma_i), e.g. with the length of the part of an open
    path that corresponds to one period of the base path (Sec. 5.4.3).
    """
    return Morphing(period_length(own) if own_length is None else float(own_length), period_length(base))


def configuration(paths: Sequence[Path], morphs: Sequence[Morphing], psi, offsets=None) -> np.ndarray:
    """Positions of all robots when each is at base coordinate psi + offset (Fig. 5.14).

    Parameters
    ----------
    paths : sequence of Path
        Gamma_i of each robot.
    morphs : sequence of Morphing
        The matching maps to base coordinates.
    psi : float or (m,) ndarray
        Base coordinate(s) of the reference robot.
    offsets : (n,) array_like, optional
        Desired base-coordinate offsets psi_i - psi (default zeros).

    Returns
    -------
    (n, 2) ndarray for a scalar psi, or (m, n, 2) for an array.
    """
    psi_arr = np.atleast_1d(np.asarray(psi, dtype=float))
    offs = np.zeros(len(paths)) if offsets is None else np.asarray(offsets, dtype=float)
    if len(paths) != len(morphs) or len(offs) != len(paths):
        raise ValueError("paths, morphs and offsets must have the same length")
    out = np.stack([np.atleast_2d(p.pos(m.s(psi_arr + o))) for p, m, o in zip(paths, morphs, offs)], axis=1)
    return out[0] if np.ndim(psi) == 0 else out
