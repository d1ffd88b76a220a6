"""Planar geometry of the simulated world: convex polygon obstacles, range sensors and
clearances (Chapter 4, Sec. 4.4.3: a ring of infra-red sensors every 30 deg with a
0.5 m range; static and moving convex polygons).

Pure numpy; imported by the simulator (ranges, collisions) and by tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PolygonObstacle", "ray_cast", "point_polygon_distance", "clearance"]

_EPS = 1e-12


@dataclass(frozen=True)
class PolygonObstacle:
    """A convex polygon translating at constant velocity.

    Parameters
    ----------
    vertices : (n, 2) array_like
        Corners at t = 0 (clockwise or counter-clockwise) [m].
    velocity : (2,) array_like
        Translation velocity [m/s].
    """

    vertices: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
            raise ValueError(f"vertices must be (n >= 3, 2), got shape {v.shape}")
        vel = np.asarray(self.velocity, dtype=float).reshape(2)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "velocity", vel)

    def at(self, t: float) -> np.ndarray:
        """(n, 2) corners at time t [s]."""
        return self.vertices + self.velocity * float(t)


def _edges(polygons) -> tuple[np.ndarray, np.ndarray]:
    """Start points (m, 2) and edge vectors (m, 2) of all polygons' edges."""
    starts, vecs = [], []
    for poly in polygons:
        p = np.asarray(poly, dtype=float)
        q = np.roll(p, -1, axis=0)
        starts.append(p)
        vecs.append(q - p)
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(starts), np.concatenate(vecs)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _inside(p: np.ndarray, poly: np.ndarray) -> bool:
    """Point in (or on) a convex polygon, either orientation."""
    q = np.roll(poly, -1, axis=0)
    c = _cross(q - poly, p - poly)
    return bool(np.all(c >= -1e-12) or np.all(c <= 1e-12))


def ray_cast(origin, heading: float, angles, max_range: float, polygons) -> np.ndarray:
    """Ranges measured by rays from ``origin`` against convex polygons.

    Parameters
    ----------
    origin : (2,)
        Sensor position [m].
    heading : float
        Robot heading [rad]; ``angles`` are body-frame bearings added to it.
    angles : (k,)
        Ray bearings in the body frame [rad].
    max_range : float
        Sensor range [m].
    polygons : list of (n, 2) arrays
        Obstacles (corners at the current time).

    Returns
    -------
    (k,) ndarray
        Distance to the first hit along each ray, ``inf`` where nothing lies within
        ``max_range``; 0 for every ray when the origin is inside an obstacle.
    """
    o = np.asarray(origin, dtype=float).reshape(2)
    a = np.asarray(angles, dtype=float).reshape(-1)
    out = np.full(a.shape, np.inf)
    if len(polygons) == 0 or a.size == 0:
        return out
    for poly in polygons:
        if _inside(o, np.asarray(poly, dtype=float)):
            return np.zeros(a.shape)
    p, e = _edges(polygons)  # (m, 2)
    d = np.stack([np.cos(heading + a), np.sin(heading + a)], axis=-1)  # (k, 2)
    w = p - o  # (m, 2)
    denom = _cross(d[:, None, :], e[None, :, :])  # (k, m)
    ok = np.abs(denom) > _EPS
    safe = np.where(ok, denom, 1.0)
    t = _cross(w[None, :, :], e[None, :, :]) / safe  # distance along the ray
    u = _cross(w[None, :, :], d[:, None, :]) / safe  # position along the edge
    hit = ok & (t >= 0.0) & (u >= -1e-12) & (u <= 1.0 + 1e-12)
    tt = np.where(hit, t, np.inf).min(axis=1)
    return np.where(tt <= max_range, tt, np.inf)


def point_polygon_distance(p, poly) -> float:
    """Signed distance from point ``p`` (2,) to a convex polygon (n, 2): negative inside."""
    x = np.asarray(p, dtype=float).reshape(2)
    v = np.asarray(poly, dtype=float)
    e = np.roll(v, -1, axis=0) - v
    w = x - v
    L2 = np.maximum(np.einsum("ij,ij->i", e, e), _EPS)
    tau = np.clip(np.einsum("ij,ij->i", w, e) / L2, 0.0, 1.0)
    dist = float(np.min(np.linalg.norm(w - tau[:, None] * e, axis=1)))
    return -dist if _inside(x, v) else dist


def clearance(center, radius: float, polygons) -> float:
    """Smallest distance from a disc (robot footprint) to any polygon; < 0 means collision.

    ``inf`` when there are no polygons.
    """
    if len(polygons) == 0:
        return float("inf")
    return min(point_polygon_distance(center, poly) for poly in polygons) - float(radius)
