"""Path coordinates of measured positions and formation slots on paths (Chapters 5-6).

Pure geometry shared by whoever needs to judge a team from positions alone (the
metrics of a run are computed from the simulator's true poses with it):

- :func:`track_coordinate`: the path coordinate s(t) of a sequence of positions, i.e. the
  projection of each position onto the path, searched near the previous one so that it
  stays continuous where a curve crosses itself (the lemniscate (5.9) at its centre) and
  counts laps on closed paths; far off the stretch followed, it moves to another stretch
  that is markedly nearer and along which the position is travelling;
- :func:`offset_points`: points o(s) = r(s) + q n(s) at lateral offset q (5.10), (A.1);
- :func:`switching_offsets`: along-track and lateral slot offsets of a robot whose slot
  moves with the quintic (5.1)-(5.3) at scheduled formation switches (Sec. 6.2.4);
- :func:`solve_coordinate`: the own path coordinate s at which s - s_d(s) equals a
  formation coordinate (fixed point, valid while |s_d'| < 1);
- :func:`wrap_near`: differences of coordinates on a closed path, modulo its length.

Everything is vectorised over time samples.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .offsets import Quintic
from .paths import Path

__all__ = ["track_coordinate", "coordinate_grid", "refine_coordinate", "offset_points", "switching_offsets", "solve_coordinate", "wrap_near"]


def wrap_near(d, period: float):
    """d mapped into [-period/2, period/2] when period > 0 (unchanged otherwise)."""
    d = np.asarray(d, dtype=float)
    return d - period * np.round(d / period) if period > 0 else d


def coordinate_grid(path, resolution: float = 0.01, extension: float = 5.0) -> tuple[np.ndarray, float, np.ndarray]:
    """The table :func:`track_coordinate` searches: path coordinates ``grid`` (a closed path's
    period in steps of about ``resolution``; an open path's length and ``extension`` beyond
    each end), their spacing ``h`` and the points ``P`` of the path there."""
    L = float(path.length)
    if path.closed:
        n = max(16, int(np.ceil(L / resolution)))
        grid = np.arange(n) * (L / n)
    else:
        n = max(16, int(np.ceil((L + 2 * extension) / resolution)) + 1)
        grid = np.linspace(-extension, L + extension, n)
    return grid, float(grid[1] - grid[0]), np.asarray(path.pos(grid))


def track_coordinate(path: Path, xy, window: float = 0.5, resolution: float = 0.01,
                     extension: float = 5.0, s0: float | None = None, reach: float = 0.5,
                     margin: float = 0.1, ambiguity: float = 1.0) -> np.ndarray:
    """Path coordinate of each position of a trajectory, continuous in time.

    Parameters
    ----------
    path : Path
    xy : (T, 2) array_like
        Positions in time order.
    window : float
        The projection of sample k is searched within +- ``window`` [m] of the projection
        of sample k-1 (a global search for k = 0), so a robot passing the crossing of a
        figure-eight keeps its branch.
    resolution : float
        Spacing of the search table [m]; the result is refined by Newton steps on the
        orthogonality condition (p - r(s)) . t(s) = 0 to well below it.
    extension : float
        Open paths are searched up to this far beyond their ends (straight extensions).
    s0 : float, optional
        Search the first sample's projection within +- ``window`` of ``s0`` instead of
        globally, and unwrap from there: continues a trajectory from a known coordinate
        (a robot that drove off its path and is back in its slot).
    reach : float
        A sample farther than this [m] from its windowed projection is off the stretch of
        path being followed, and the whole path is searched as well (see Notes).
    margin : float
        The nearest point of the whole path replaces the windowed one only when it is
        nearer by more than this [m] (hysteresis where two stretches are about as near,
        e.g. across the middle of a lobe).
    ambiguity : float
        On a closed path that point is reached the shorter way round (its lap is the one
        nearest the windowed projection), and only when the shorter way is shorter than
        half the period by more than this [m].

    Returns
    -------
    (T,) ndarray
        s for each sample, unwrapped over laps; on a closed path the first sample lies in
        [-L/2, L/2), so a team starting near the path's origin starts near s = 0 (or near
        ``s0`` when given).

    Notes
    -----
    Within ``reach`` of the stretch it follows, the windowed search is the continuous
    projection through the tube about that stretch and is used alone: a robot on its lane
    keeps its branch through a crossing. Farther out it follows the nearest point of one
    stretch, which can slide along it against the robot's motion: a robot held off the
    lemniscate's lane cut across the lobe to the crossing and on along the other branch,
    the window slid back along the first branch and the truth's coordinate lost a lap
    (12.06 m) while the robot drove forward (docs/journal/faults.md, "A grading artefact, not
    a lost robot"; docs/reference/metrics.md, "M1 — Path coordinate of a true position").
    So, off the stretch followed, the coordinate moves to the nearest point of the whole
    path when four things hold: (i) it is nearer by ``margin``; (ii) the robot's displacement
    since the last sample runs forward along the tangent there, and farther than along the
    tangent of the stretch followed (its direction of travel: a robot holding a lateral
    offset q (5.10) moves along its own stretch and keeps it where it passes close to another
    branch, and a robot held still keeps its coordinate); (iii) on a closed path, the shorter
    way round is not within ``ambiguity`` of half a lap (next to a crossing both ways are
    about L/2, and no jump is made); (iv) the point lies ahead, unless the robot is moving
    backward along the stretch followed (then that stretch is the wrong branch: a robot
    turning round a disc next to the crossing moves partly along the other branch, and a
    jump back there took 5 m off its progress). The paths are followed forward (increasing s).
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    T = len(xy)
    if T == 0:
        return np.zeros(0)
    L = float(path.length)
    grid, h, P = coordinate_grid(path, resolution, extension)
    n = len(grid)
    w = max(1, int(np.ceil(window / h)))
    idx = np.empty(T, dtype=np.int64)
    if s0 is None:
        d0 = P - xy[0]
        i = int(np.argmin(np.einsum("ij,ij->i", d0, d0)))
        if path.closed and grid[i] >= 0.5 * L:
            i -= n
        first = 1
    else:  # the first sample is searched near s0, like every later one near the one before
        i = int(round(s0 / h)) if path.closed else int(np.clip(round((s0 - grid[0]) / h), 0, n - 1))
        first = 0
    idx[0] = i
    # the table padded by the window at both ends (wrapped round a closed path, the end points
    # repeated on an open one), so each search window is one slice: row r of the padded table
    # is P[(r - w) mod n] or P[clip(r - w, 0, n - 1)], the candidates of i in their order
    pad = (np.concatenate([P[n - w:], P, P[:w]]) if path.closed and w <= n
           else P[np.mod(np.arange(-w, n + w), n)] if path.closed
           else np.concatenate([np.repeat(P[:1], w, 0), P, np.repeat(P[-1:], w, 0)]))
    reach2 = reach * reach
    half = (0.5 * L - ambiguity) / h  # the longest jump round a closed path [table steps]
    tangent = None  # unit tangents of the table, made when first needed
    for k in range(first, T):
        r = i % n if path.closed else i  # an open path's i is a table index already
        d = pad[r:r + 2 * w + 1] - xy[k]
        dd = np.einsum("ij,ij->i", d, d)
        j = int(np.argmin(dd))
        i = i - w + j if path.closed else min(max(i - w + j, 0), n - 1)
        if dd[j] > reach2 and k > 0:  # off the stretch followed: the whole path is searched
            if tangent is None:
                th = path.frame(grid)[2]
                tangent = np.column_stack([np.cos(th), np.sin(th)])
            i = _reacquire(P, tangent, xy[k], xy[k] - xy[k - 1], i, float(np.sqrt(dd[j])) - margin,
                           n if path.closed else 0, half)
        idx[k] = i
    return refine_coordinate(path, xy, idx * h if path.closed else grid[idx], h)


def _reacquire(P: np.ndarray, tangent: np.ndarray, p: np.ndarray, dp: np.ndarray, i: int, nearer: float,
               n: int, half: float) -> int:
    """Table index of the point of ``P`` nearest to ``p`` when it is nearer than ``nearer``
    [m], the displacement ``dp`` since the last sample runs farther along its ``tangent`` than
    along the windowed index ``i``'s (and forward along it), on a closed path (``n`` its table
    length, 0 for an open one) no more than ``half`` table steps the shorter way round, and it
    lies ahead of ``i`` unless ``dp`` runs backward along ``i``'s tangent; else ``i``."""
    d = P - p
    dd = np.einsum("ij,ij->i", d, d)
    g = int(np.argmin(dd))
    along_i = float(dp @ tangent[i % len(P)])
    if nearer <= 0.0 or dd[g] >= nearer * nearer or dp @ tangent[g] <= max(along_i, 0.0):
        return i
    if n:
        g += n * int(np.round((i - g) / n))  # the lap nearest the windowed projection
        if abs(g - i) > half:
            return i
    # back only off a stretch the robot is moving backward along (the one it follows is the
    # wrong branch): a robot turning round a disc next to the lemniscate's crossing moves
    # partly along the other branch, and a jump back there took 5 m off its progress
    # (docs/reference/metrics.md, path coordinate of a true position (M1))
    return g if g > i or along_i < 0.0 else i


def refine_coordinate(path, xy: np.ndarray, s: np.ndarray, h: float, steps: int = 4) -> np.ndarray:
    """``steps`` Newton steps on ``(p - r(s)) . t(s) = 0`` from ``s`` for the points ``xy`` (T x 2),
    each clipped to ``h`` (the search table's spacing, :func:`coordinate_grid`)."""
    for _ in range(steps):
        x, y, th, kap = path.frame(s)
        ex, ey = xy[:, 0] - x, xy[:, 1] - y
        c, sn = np.cos(th), np.sin(th)
        f = ex * c + ey * sn
        df = -1.0 + kap * (-ex * sn + ey * c)
        step = np.where(np.abs(df) > 1e-9, -f / np.where(np.abs(df) > 1e-9, df, 1.0), 0.0)
        s = s + np.clip(step, -h, h)
    return s


def offset_points(path: Path, s, q) -> np.ndarray:
    """o(s) = r(s) + q n(s), n the left unit normal (5.10), (A.1); (..., 2) for array s."""
    s = np.atleast_1d(np.asarray(s, dtype=float))
    q = np.broadcast_to(np.asarray(q, dtype=float), s.shape)
    x, y, th, _ = path.frame(s)
    return np.stack([x - q * np.sin(th), y + q * np.cos(th)], axis=-1)


def switching_offsets(slots: Sequence[Sequence[float]], switch_at: Sequence[float], transition_m: float, s):
    """Slot offsets of one robot along its own path coordinate s (Sec. 6.2.4, (5.1)-(5.3)).

    The robot holds slot k = (s_d, q) until its formation coordinate s - s_d reaches
    ``switch_at[k]``, i.e. until s = switch_at[k] + s_d,k; from there both offsets move to
    slot k+1 with the quintic (5.3) over ``transition_m`` metres of s.

    Returns
    -------
    (s_d, q, in_transition) arrays shaped like s.
    """
    s = np.asarray(s, dtype=float)
    sd = np.full(s.shape, float(slots[0][0]))
    q = np.full(s.shape, float(slots[0][1]))
    moving = np.zeros(s.shape, dtype=bool)
    for k, xi_k in enumerate(switch_at):
        (sd0, q0), (sd1, q1) = slots[k], slots[k + 1]
        s_a = float(xi_k) + float(sd0)
        s_b = s_a + float(transition_m)
        after = s > s_a
        sd = np.where(after, Quintic(float(sd0), float(sd1), s_a, s_b)(s)[0], sd)
        q = np.where(after, Quintic(float(q0), float(q1), s_a, s_b)(s)[0], q)
        moving |= after & (s < s_b)
    return sd, q, moving


def solve_coordinate(xi, s_d_of, iterations: int = 60) -> np.ndarray:
    """The s with s - s_d(s) = xi, by the fixed point s <- xi + s_d(s) (a contraction while
    |s_d'| < 1, which the quintic keeps for transitions longer than 1.875 |delta s_d|)."""
    xi = np.asarray(xi, dtype=float)
    s = xi + s_d_of(xi)
    for _ in range(iterations):
        s_new = xi + s_d_of(s)
        if np.allclose(s_new, s, atol=1e-9, rtol=0.0):
            return s_new
        s = s_new
    return s
