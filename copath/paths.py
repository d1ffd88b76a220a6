"""Reference paths re-parameterised by arc length (docs/reference/conventions.md, arc-length paths (C2)).

Every reference curve of the dissertation is "numerically parameterized by the path
length s". A :class:`Path` wraps a parametric curve r(phi) and exposes, for any arc
length s (scalars or arrays, vectorised):

- ``pos(s)``: (..., 2) position,
- ``theta(s)``: tangent angle, continuous along s (unwrapped, also across laps),
- ``kappa(s)``: signed curvature, positive for a left (CCW) turn,
- ``dkappa(s)``: d kappa / d s,
- ``length``, ``closed``, ``wrap(s)`` and ``nearest(p, s_guess)``.

Position, tangent and curvature are evaluated from the parametric curve itself at
phi(s), so only the map s -> phi is tabulated; geometry is exact up to that map.
Open paths are extended beyond their ends along the end tangents (straight lines,
zero curvature), so a robot that overshoots still has a well-defined reference.

Curves: the eight curve (4.14), the lemniscate (5.9), ellipse/circle (5.30)-(5.32)
with rotation and centre, sinusoid, straight line, and a C2 cubic spline through
user waypoints (E6.6).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = [
    "Path",
    "PathTable",
    "eight_curve",
    "lemniscate",
    "ellipse",
    "circle",
    "sinusoid",
    "line",
    "spline",
    "make_path",
    "PATH_TYPES",
    "wrap_to_pi",
]


def wrap_to_pi(a):
    """Wrap angles to (-pi, pi] with atan2(sin, cos) (docs/reference/conventions.md, frames and angles (C1)).

    A Python number takes a scalar path (no numpy round trip: estimators call this per
    measurement); arrays are wrapped element-wise."""
    if isinstance(a, (float, int)):
        return math.atan2(math.sin(a), math.cos(a))
    a = np.asarray(a, dtype=float)
    out = np.arctan2(np.sin(a), np.cos(a))
    return float(out) if out.ndim == 0 else out


CurveFn = Callable[[np.ndarray], np.ndarray]

_SCALARS = (float, int, np.float64)
"""Types of an arc length that :meth:`Path.frame` looks up without numpy arrays."""


@dataclass(frozen=True)
class _Curve:
    """A parametric curve r(phi) on [phi0, phi1]; r maps (n,) -> (n, 2)."""

    r: CurveFn
    phi0: float
    phi1: float
    closed: bool
    name: str


def _placed(x: np.ndarray, y: np.ndarray, rotation: float, center) -> np.ndarray:
    """(..., 2) points (x, y) rotated by ``rotation`` and moved to ``center``, written
    into one array (``np.stack`` of two one-line arrays costs more than the arithmetic
    on the nine stencil points of :meth:`Path.frame`)."""
    c, s = math.cos(rotation), math.sin(rotation)
    out = np.empty(np.shape(x) + (2,))
    out[..., 0] = c * x - s * y + center[0]
    out[..., 1] = s * x + c * y + center[1]
    return out


class Path:
    """An arc-length parameterised path built from a parametric curve.

    Parameters
    ----------
    curve : _Curve
        The parametric curve.
    samples : int
        Number of samples of the s -> phi table (default 20001).
    """

    def __init__(self, curve: _Curve, samples: int = 20001) -> None:
        self.name = curve.name
        self.closed = curve.closed
        self._r = curve.r
        phi = np.linspace(curve.phi0, curve.phi1, samples)
        self._h = 1e-4 * max(1.0, abs(curve.phi1 - curve.phi0) / (2 * math.pi))
        d1 = self._d1(phi)
        speed = np.hypot(d1[:, 0], d1[:, 1])
        if np.any(speed < 1e-9):
            raise ValueError(f"path {curve.name!r} has a singular point (zero speed)")
        # Cumulative arc length by the trapezoid rule on a fine grid, refined once
        # with Simpson on midpoints for accuracy (|error| ~ 1e-10 m here).
        mid = 0.5 * (phi[1:] + phi[:-1])
        dm = self._d1(mid)
        sm = np.hypot(dm[:, 0], dm[:, 1])
        seg = (phi[1:] - phi[:-1]) * (speed[1:] + 4 * sm + speed[:-1]) / 6.0
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(s[-1])
        self._s_tab = s
        self._phi_tab = phi
        self._dphi_tab = 1.0 / speed  # d phi / d s at the nodes (cubic Hermite map s -> phi)
        th = np.arctan2(d1[:, 1], d1[:, 0])
        self._theta_tab = np.unwrap(th)
        self.winding = (
            round((self._theta_tab[-1] - self._theta_tab[0]) / (2 * math.pi)) if self.closed else 0
        )
        k = self._kappa_phi(phi)
        self._dkappa_tab = np.gradient(k, s)
        p0 = self._r(np.array([curve.phi0]))[0]
        p1 = self._r(np.array([curve.phi1]))[0]
        if self.closed and np.hypot(*(p1 - p0)) > 1e-6 * max(1.0, self.length):
            raise ValueError(f"path {curve.name!r} is declared closed but its ends differ")
        self._cas = None
        self._tables: dict[float, PathTable] = {}
        h1, h2 = self._h, self._h * 10
        self._stencil = np.array([0.0, h1, -h1, 2 * h1, -2 * h1, h2, -h2, 2 * h2, -2 * h2])
        """Offsets in phi of the nine curve points :meth:`frame` evaluates per arc length."""
        self._s_list, self._phi_list, self._dphi_list = s.tolist(), phi.tolist(), self._dphi_tab.tolist()
        """The s -> phi table as Python floats, for the scalar look-up."""
        self._theta_list = self._theta_tab.tolist()
        """The heading table as Python floats (:meth:`_interp_theta`)."""

    # -- derivatives of the parametric curve (5-point stencils) -------------------
    def _d1(self, phi: np.ndarray) -> np.ndarray:
        h = self._h
        r = self._r
        return (-r(phi + 2 * h) + 8 * r(phi + h) - 8 * r(phi - h) + r(phi - 2 * h)) / (12 * h)

    def _d2(self, phi: np.ndarray) -> np.ndarray:
        h = self._h * 10
        r = self._r
        return (
            -r(phi + 2 * h) + 16 * r(phi + h) - 30 * r(phi) + 16 * r(phi - h) - r(phi - 2 * h)
        ) / (12 * h * h)

    def _kappa_phi(self, phi: np.ndarray) -> np.ndarray:
        d1 = self._d1(phi)
        d2 = self._d2(phi)
        num = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
        return num / np.hypot(d1[:, 0], d1[:, 1]) ** 3

    # -- arc length handling --------------------------------------------------------
    def wrap(self, s):
        """Map s into [0, length) for closed paths; identity for open paths."""
        s = np.asarray(s, dtype=float)
        out = np.mod(s, self.length) if self.closed else s
        return float(out) if out.ndim == 0 else out

    def _split(self, s):
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if self.closed:
            laps = np.floor(s / self.length)
            return s - laps * self.length, laps, np.zeros_like(s)
        inside = np.clip(s, 0.0, self.length)
        return inside, np.zeros_like(s), s - inside

    def _phi(self, s_in: np.ndarray) -> np.ndarray:
        """phi(s) by cubic Hermite interpolation with the exact slopes 1/|r'(phi)|, so
        |d pos / d s| = 1 to about 1e-10 (linear interpolation would leave 1e-4)."""
        S = self._s_tab
        i = np.clip(np.searchsorted(S, s_in, side="right") - 1, 0, len(S) - 2)
        h = S[i + 1] - S[i]
        u = (s_in - S[i]) / h
        u2, u3 = u * u, u * u * u
        return ((2 * u3 - 3 * u2 + 1) * self._phi_tab[i] + (u3 - 2 * u2 + u) * h * self._dphi_tab[i]
                + (-2 * u3 + 3 * u2) * self._phi_tab[i + 1] + (u3 - u2) * h * self._dphi_tab[i + 1])

    @staticmethod
    def _out(x, scalar):
        return x[0] if scalar else x

    def pos(self, s) -> np.ndarray:
        """Position (..., 2) at arc length s."""
        scalar = np.ndim(s) == 0
        s_in, _, extra = self._split(s)
        p = self._r(self._phi(s_in))
        if np.any(extra != 0.0):
            th = self._theta_raw(s_in)
            p = p + extra[:, None] * np.stack([np.cos(th), np.sin(th)], axis=-1)
        return self._out(p, scalar)

    def _theta_raw(self, s_in: np.ndarray) -> np.ndarray:
        d1 = self._d1(self._phi(s_in))
        raw = np.arctan2(d1[:, 1], d1[:, 0])
        ref = np.interp(s_in, self._s_tab, self._theta_tab)
        return raw + 2 * math.pi * np.round((ref - raw) / (2 * math.pi))

    def theta(self, s):
        """Tangent angle at s, continuous in s (for closed paths also across laps)."""
        scalar = np.ndim(s) == 0
        s_in, laps, _ = self._split(s)
        th = self._theta_raw(s_in) + 2 * math.pi * self.winding * laps
        return float(th[0]) if scalar else th

    def kappa(self, s):
        """Signed curvature at s (docs/reference/conventions.md, frames and angles (C1)); zero beyond open ends."""
        scalar = np.ndim(s) == 0
        s_in, _, extra = self._split(s)
        k = self._kappa_phi(self._phi(s_in))
        k = np.where(extra != 0.0, 0.0, k)
        return float(k[0]) if scalar else k

    def dkappa(self, s):
        """d kappa / d s at s (tabulated by finite differences)."""
        scalar = np.ndim(s) == 0
        s_in, _, extra = self._split(s)
        dk = np.interp(s_in, self._s_tab, self._dkappa_tab)
        dk = np.where(extra != 0.0, 0.0, dk)
        return float(dk[0]) if scalar else dk

    def frame(self, s):
        """(x, y, theta, kappa) at s, each shaped like s, from one evaluation of the curve.

        Scalars in, floats out; this is the hot path of the controllers (one stencil of
        nine curve points per s instead of separate calls for position, tangent and
        curvature)."""
        if type(s) in _SCALARS:
            return self._frame_scalar(float(s))
        scalar = np.ndim(s) == 0
        s_in, laps, extra = self._split(s)
        phi = self._phi(s_in)
        h1, h2 = self._h, self._h * 10
        offs = self._stencil
        R = self._r((phi[None, :] + offs[:, None]).reshape(-1)).reshape(9, -1, 2)
        d1 = (-R[3] + 8 * R[1] - 8 * R[2] + R[4]) / (12 * h1)
        d2 = (-R[7] + 16 * R[5] - 30 * R[0] + 16 * R[6] - R[8]) / (12 * h2 * h2)
        sp = np.hypot(d1[:, 0], d1[:, 1])
        k = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / sp**3
        raw = np.arctan2(d1[:, 1], d1[:, 0])
        ref = np.interp(s_in, self._s_tab, self._theta_tab)
        th = raw + 2 * math.pi * np.round((ref - raw) / (2 * math.pi))
        pos = R[0]
        if np.any(extra != 0.0):
            pos = pos + extra[:, None] * np.stack([np.cos(th), np.sin(th)], axis=-1)
            k = np.where(extra != 0.0, 0.0, k)
        th = th + 2 * math.pi * self.winding * laps
        if scalar:
            return float(pos[0, 0]), float(pos[0, 1]), float(th[0]), float(k[0])
        return pos[:, 0], pos[:, 1], th, k

    def _frame_scalar(self, s: float) -> tuple[float, float, float, float]:
        """:meth:`frame` at one arc length given as a Python number: the same operations
        in the same order on Python floats, so the result is bit-identical to the array
        path, without its numpy overhead on one-element arrays. The curve and the
        transcendental functions are still numpy's (the curve's nine stencil points in
        one call; ``arctan2``, ``hypot`` and ``power`` as ufuncs), since libm's and numpy's
        differ in the last bit where numpy has SIMD routines of its own (AVX-512;
        docs/journal/performance.md, profile of E5.4 (P12))."""
        L = self.length
        if self.closed:
            laps = math.floor(s / L)
            s_in, extra = s - laps * L, 0.0
        else:
            laps = 0.0
            s_in = min(max(s, 0.0), L)
            extra = s - s_in
        S = self._s_tab
        i = min(max(bisect.bisect_right(self._s_list, s_in) - 1, 0), len(S) - 2)
        s0, s1 = self._s_list[i], self._s_list[i + 1]
        h = s1 - s0
        u = (s_in - s0) / h
        u2, u3 = u * u, u * u * u
        phi = ((2 * u3 - 3 * u2 + 1) * self._phi_list[i] + (u3 - 2 * u2 + u) * h * self._dphi_list[i]
               + (-2 * u3 + 3 * u2) * self._phi_list[i + 1] + (u3 - u2) * h * self._dphi_list[i + 1])
        h1, h2 = self._h, self._h * 10
        R = self._r(phi + self._stencil).tolist()
        d1x = (-R[3][0] + 8 * R[1][0] - 8 * R[2][0] + R[4][0]) / (12 * h1)
        d1y = (-R[3][1] + 8 * R[1][1] - 8 * R[2][1] + R[4][1]) / (12 * h1)
        d2x = (-R[7][0] + 16 * R[5][0] - 30 * R[0][0] + 16 * R[6][0] - R[8][0]) / (12 * h2 * h2)
        d2y = (-R[7][1] + 16 * R[5][1] - 30 * R[0][1] + 16 * R[6][1] - R[8][1]) / (12 * h2 * h2)
        sp = float(np.hypot(d1x, d1y))  # libm's hypot: math.hypot rounds differently (safety filter's cost (P13))
        k = (d1x * d2y - d1y * d2x) / float(np.power(sp, 3))  # numpy's pow, as the array path (not libm's on AVX-512)
        raw = float(np.arctan2(d1y, d1x))  # numpy's: on AVX-512 machines it is not libm's (math.atan2)
        ref = self._interp_theta(s_in, i)
        th = raw + 2 * math.pi * round((ref - raw) / (2 * math.pi))
        x, y = R[0]
        if extra != 0.0:
            x = x + extra * float(np.cos(th))
            y = y + extra * float(np.sin(th))
            k = 0.0
        th = th + 2 * math.pi * self.winding * laps
        return x, y, th, k

    def _interp_theta(self, x: float, i: int) -> float:
        """``np.interp(x, s_tab, theta_tab)`` of one arc length on Python floats, the same
        operations as numpy's (``arr_interp``: the end values outside the table, a node's own
        value at a node, else slope (y1 - y0) / (x1 - x0) times (x - x0) plus y0); ``i`` is
        :meth:`_frame_scalar`'s interval, clipped to the table, so x lies in it or at an end."""
        S, Y = self._s_list, self._theta_list
        if not S[i] < x < S[i + 1]:  # at a node, beyond an end, or NaN: numpy's own
            return float(np.interp(x, self._s_tab, self._theta_tab))
        return (Y[i + 1] - Y[i]) / (S[i + 1] - S[i]) * (x - S[i]) + Y[i]

    def normal(self, s) -> np.ndarray:
        """Left unit normal n = (-sin theta, cos theta) at s."""
        th = np.asarray(self.theta(s))
        return np.stack([-np.sin(th), np.cos(th)], axis=-1)

    def nearest(self, p, s_guess: float, window: float = 1.0, resolution: float = 0.005) -> float:
        """Arc length of the path point nearest to p, searched in s_guess +- window.

        The search samples the window and refines with Newton steps on the
        orthogonality condition (p - r(s)) . t(s) = 0, so the cost is independent
        of the path length. The returned s is not wrapped (it stays near s_guess).
        """
        p = np.asarray(p, dtype=float).reshape(2)
        n = max(3, int(2 * window / resolution) + 1)
        cand = np.linspace(s_guess - window, s_guess + window, n)
        if not self.closed:
            cand = np.clip(cand, -window, self.length + window)
        d = self.pos(cand) - p
        s = float(cand[np.argmin(np.einsum("ij,ij->i", d, d))])
        for _ in range(4):
            th = self.theta(s)
            t = np.array([math.cos(th), math.sin(th)])
            e = p - self.pos(s)
            f = float(e @ t)
            k = self.kappa(s)
            # derivative of f w.r.t. s: -1 + kappa * (e . n)
            df = -1.0 + k * float(e @ np.array([-t[1], t[0]]))
            if abs(df) < 1e-9:
                break
            step = -f / df
            step = max(-resolution, min(resolution, step))
            s += step
            if abs(step) < 1e-10:
                break
        return s

    def project(self, p, s_guess: float | None = None, window: float = 1.0,
                resolution: float = 0.005) -> float:
        """Arc length of the point of the path nearest to the position p (the
        projection of a pose onto the path, e.g. the start of a virtual vehicle).

        Without ``s_guess`` the whole path is searched (a grid of 2 cm, at least 200
        points, refined by :meth:`nearest`). With ``s_guess`` only s_guess +- ``window``
        is searched, so successive projections stay continuous along a self-crossing
        curve (the lemniscate (5.9) and the eight curve (4.14) cross themselves) instead
        of jumping to the other branch at the crossing. The result is not wrapped.
        """
        p = np.asarray(p, dtype=float).reshape(-1)[:2]
        if s_guess is not None:
            return self.nearest(p, float(s_guess), window=window, resolution=resolution)
        n = max(200, int(self.length / 0.02))
        s = np.linspace(0.0, self.length, n)
        d = self.pos(s) - p
        s0 = float(s[np.argmin(np.einsum("ij,ij->i", d, d))])
        return self.nearest(p, s0, window=self.length / n * 2, resolution=resolution)

    def table(self, step: float = 1e-3) -> "PathTable":
        """The :class:`PathTable` of this path on a grid of ``step`` metres (built once
        per step size and shared by every controller using this path object)."""
        key = float(step)
        if key not in self._tables:
            self._tables[key] = PathTable(self, step)
        return self._tables[key]

    # -- CasADi -------------------------------------------------------------------
    def casadi(self, grid_step: float = 0.01):
        """CasADi functions ``x, y, theta, kappa`` of a (symbolic) arc length.

        Built once per path: B-spline interpolants through the samples of the path's
        :class:`PathTable` on a grid of ``grid_step`` (open paths include their straight
        extensions of one path length at both ends), evaluated at ``fmod(s, length)`` for
        closed paths so s may be a symbolic state that grows without bound
        (docs/reference/conventions.md, arc-length paths (C2)). ``theta`` is continuous within one lap; wrap angle
        differences with atan2(sin, cos).
        """
        if self._cas is not None:
            return self._cas
        import casadi as ca

        table = self.table(min(grid_step, self.length / 49))
        grid = table.grid
        x, y, th, k = table.values[:4]
        fx = ca.interpolant(f"{self.name}_x", "bspline", [grid], x)
        fy = ca.interpolant(f"{self.name}_y", "bspline", [grid], y)
        fth = ca.interpolant(f"{self.name}_theta", "bspline", [grid], th)
        fk = ca.interpolant(f"{self.name}_kappa", "bspline", [grid], k)
        s = ca.MX.sym("s")
        sw = ca.fmod(ca.fmod(s, self.length) + self.length, self.length) if self.closed else s
        lap = (s - sw) / self.length if self.closed else 0
        self._cas = {
            "x": ca.Function("path_x", [s], [fx(sw)]),
            "y": ca.Function("path_y", [s], [fy(sw)]),
            "theta": ca.Function("path_theta", [s], [fth(sw) + 2 * math.pi * self.winding * lap]),
            "kappa": ca.Function("path_kappa", [s], [fk(sw)]),
        }
        return self._cas

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        return f"Path({self.name!r}, {kind}, length={self.length:.4f} m)"


class PathTable:
    """One tabulated path: fast x, y, theta, kappa and dkappa/ds at many arc lengths.

    Solvers and horizons evaluate the geometry at N+1 arc lengths every control step;
    :class:`Path` evaluates the parametric curve with finite-difference stencils
    (accurate but about 1 ms per call), so the geometry is tabulated once here on a
    uniform grid of ``step`` metres (default 1 mm: linear-interpolation errors below
    1e-6 m and 1e-4 1/m on the published paths) and looked up by linear interpolation.
    Closed paths wrap (theta gains 2 pi per lap times the winding number); open paths
    are tabulated on [-length, 2 length] including their straight extensions and
    clamped beyond.

    Besides the (5, n) look-up ``table(s)`` it offers the :class:`Path` methods that
    geometry code needs (``pos``, ``theta``, ``kappa``, ``dkappa``, ``frame``), so
    offset curves (Appendix A) and the controllers' references can be served from the
    table instead of the curve. Build it with :meth:`Path.table` to share it.
    """

    def __init__(self, path: Path, step: float = 1e-3) -> None:
        if not step > 0:
            raise ValueError(f"step = {step!r} is not allowed; must be > 0 [m]")
        self.path = path
        self.name = path.name
        self.closed = bool(path.closed)
        self.length = float(path.length)
        self.winding = getattr(path, "winding", 0)
        lo, hi = (0.0, self.length) if self.closed else (-self.length, 2 * self.length)
        n = int(math.ceil((hi - lo) / step)) + 1
        grid = np.linspace(lo, hi, n)
        x, y, th, k = path.frame(grid)
        dk = np.atleast_1d(path.dkappa(grid))
        self._lo, self._h, self._n = lo, (hi - lo) / (n - 1), n
        self._tab = np.stack([x, y, th, k, dk])
        self.grid = grid
        """(n,) arc lengths of the samples [m] (uniform)."""
        self._winding = 2 * math.pi * self.winding

    def __call__(self, s) -> np.ndarray:
        """(5, n) rows x, y, theta, kappa, dkappa at arc lengths s (n,)."""
        s = np.atleast_1d(np.asarray(s, float))
        laps = np.zeros_like(s)
        if self.closed:
            laps = np.floor(s / self.length)
            s = s - laps * self.length
        f = np.clip((s - self._lo) / self._h, 0.0, self._n - 1.000001)
        i = f.astype(int)
        w = f - i
        out = self._tab[:, i] * (1 - w) + self._tab[:, i + 1] * w
        if self.closed:
            out[2] += self._winding * laps
        return out

    @property
    def values(self) -> np.ndarray:
        """(5, n) samples x, y, theta, kappa, dkappa at :attr:`grid` (read-only view)."""
        v = self._tab.view()
        v.flags.writeable = False
        return v

    def pose(self, s: float) -> tuple[float, float, float, float]:
        """(x, y, theta, kappa) at one arc length."""
        v = self(s)[:, 0]
        return float(v[0]), float(v[1]), float(v[2]), float(v[3])

    def wrap(self, s):
        """Map s into [0, length) for closed paths; identity for open paths."""
        return self.path.wrap(s)

    def pos(self, s) -> np.ndarray:
        """Position, shaped like s plus a last axis of 2."""
        g = self(s)
        return np.stack([g[0], g[1]], axis=-1).reshape(np.shape(s) + (2,))

    def theta(self, s):
        """Tangent angle, continuous in s (also across laps), shaped like s."""
        return self(s)[2].reshape(np.shape(s))

    def kappa(self, s):
        """Signed curvature, shaped like s."""
        return self(s)[3].reshape(np.shape(s))

    def dkappa(self, s):
        """d kappa / d s, shaped like s."""
        return self(s)[4].reshape(np.shape(s))

    def frame(self, s):
        """(x, y, theta, kappa) at s, each shaped like s (floats for a scalar s)."""
        g = self(s)
        if np.ndim(s) == 0:
            return float(g[0, 0]), float(g[1, 0]), float(g[2, 0]), float(g[3, 0])
        shape = np.shape(s)
        return tuple(g[i].reshape(shape) for i in range(4))

    def __repr__(self) -> str:
        return f"PathTable({self.name!r}, step={self._h:.2e} m)"


# -- curve constructors ------------------------------------------------------------


def eight_curve(ax: float = 1.8, ay: float = 1.2, rotation: float = 0.0, center=(0.0, 0.0)) -> Path:
    """Eight curve (4.14): x = ax sin(t), y = ay sin(2t) (the (0.4 phi, 0.8 phi) of the
    text traces the same geometry). Length 12.86 m for the published (1.8, 1.2)."""

    def r(t):
        return _placed(ax * np.sin(t), ay * np.sin(2 * t), rotation, center)

    return Path(_Curve(r, 0.0, 2 * math.pi, True, "eight"))


def lemniscate(a: float = 2.3, rotation: float = 0.0, center=(0.0, 0.0)) -> Path:
    """Lemniscate of Bernoulli (5.9): x = a cos t / (1 + sin^2 t), y = a sin t cos t / (1 + sin^2 t)."""

    def r(t):
        st, ct = np.sin(t), np.cos(t)
        d = 1.0 + st**2
        return _placed(a * ct / d, a * st * ct / d, rotation, center)

    return Path(_Curve(r, 0.0, 2 * math.pi, True, "lemniscate"))


def ellipse(a: float, b: float, rotation: float = 0.0, center=(0.0, 0.0), phase: float = 0.0) -> Path:
    """Ellipse x = a cos t, y = b sin t, rotated by ``rotation`` about the origin and
    moved to ``center`` (5.30)-(5.31); s = 0 at t = ``phase``; counter-clockwise."""

    def r(t):
        return _placed(a * np.cos(t), b * np.sin(t), rotation, center)

    return Path(_Curve(r, phase, phase + 2 * math.pi, True, "ellipse"))


def circle(radius: float, rotation: float = 0.0, center=(0.0, 0.0), phase: float = 0.0) -> Path:
    """Circle of ``radius`` (counter-clockwise), e.g. the E4.4 reference and (5.32)."""
    p = ellipse(radius, radius, rotation, center, phase)
    p.name = "circle"
    return p


def sinusoid(
    amplitude: float, wavelength: float, length: float, rotation: float = 0.0, origin=(0.0, 0.0)
) -> Path:
    """Open sinusoid y = A sin(2 pi x / wavelength) for x in [0, length] (E5.6, chosen)."""
    w = 2 * math.pi / wavelength

    def r(t):
        return _placed(t, amplitude * np.sin(w * t), rotation, origin)

    return Path(_Curve(r, 0.0, length, False, "sinusoid"))


def line(start=(0.0, 0.0), heading: float = 0.0, length: float = 10.0) -> Path:
    """Straight segment from ``start`` along ``heading`` [rad] of ``length`` [m]."""
    c, s = math.cos(heading), math.sin(heading)

    def r(t):
        return np.stack([start[0] + c * t, start[1] + s * t], -1)

    return Path(_Curve(r, 0.0, length, False, "line"))


def spline(waypoints, closed: bool = False) -> Path:
    """C2 cubic spline through waypoints (chord-length parameter); periodic if closed."""
    from scipy.interpolate import CubicSpline

    pts = np.asarray(waypoints, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        raise ValueError(f"waypoints must be a list of at least 3 [x, y] pairs, got shape {pts.shape}")
    if closed and np.hypot(*(pts[-1] - pts[0])) > 1e-9:
        pts = np.vstack([pts, pts[:1]])
    chord = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    if np.any(np.diff(chord) <= 0):
        raise ValueError("waypoints must not repeat consecutively")
    cs = CubicSpline(chord, pts, bc_type="periodic" if closed else "natural")
    t1 = float(chord[-1])

    if closed:

        def r(t):
            return cs(np.mod(t, t1))

    else:

        def r(t):
            return cs(t)  # cubic extrapolation only within the finite-difference stencil

    return Path(_Curve(r, 0.0, t1, closed, "spline"))


_SIZE_KEYS = frozenset({"ax", "ay", "a", "b", "radius", "wavelength", "length"})
"""Curve keys that are sizes and must be positive (``amplitude`` may be negative: a mirrored sinusoid)."""

PATH_TYPES: dict[str, Callable[..., Path]] = {
    "eight": eight_curve,
    "lemniscate": lemniscate,
    "ellipse": ellipse,
    "circle": circle,
    "sinusoid": sinusoid,
    "line": line,
    "spline": spline,
}


def make_path(spec: dict) -> Path:
    """Build a path from a scenario table such as ``{type = "ellipse", a = 1.5, b = 1.0}``.

    Raises ValueError naming the key, the value and what is allowed.
    """
    import inspect

    if not isinstance(spec, dict):
        raise ValueError(f"a path must be a table, got {spec!r}")
    kind = spec.get("type")
    if kind not in PATH_TYPES:
        raise ValueError(f"path type = {kind!r} is not allowed; choose one of {sorted(PATH_TYPES)}")
    fn = PATH_TYPES[kind]
    params = inspect.signature(fn).parameters
    kwargs = {k: v for k, v in spec.items() if k != "type"}
    for k in kwargs:
        if k not in params:
            raise ValueError(
                f"path key {k!r} (= {kwargs[k]!r}) is not allowed for type {kind!r}; allowed: {sorted(params)}"
            )
    missing = [p.name for p in params.values() if p.default is inspect.Parameter.empty and p.name not in kwargs]
    if missing:
        raise ValueError(f"path of type {kind!r} needs keys {missing}")
    for k in _SIZE_KEYS.intersection(kwargs):
        v = kwargs[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
            raise ValueError(f"{k} = {v!r} is not allowed; a curve size must be a number > 0")
    try:
        return fn(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"path {spec!r}: {exc}") from exc
