"""Navigation to a target with collision avoidance (Sec. 6.2.2, (6.10)-(6.15)).

- :func:`polar_control`: the law (6.11) for the polar error dynamics (6.10) of the
  unicycle (3.3): v = gamma tanh(e) cos(alpha),
  omega = k_c alpha + gamma tanh(e)/e sin(alpha) cos(alpha).
- :func:`repulsive_shift`: the potential field (6.12)-(6.15) that moves the target away
  from nearby robots: g_new = g + sum_o F(R_o) (p - p_o)/R_o (docs/reference/derivations.md, repulsive target shift (D9);
  docs/reference/ambiguities.md, several obstacles in (6.12)-(6.15) (A25): displacements of several obstacles are summed), with the magnitude
  clipped and a sideways component that breaks the collinear standstill.
- :func:`parking_point`: where a robot without a role waits: just outside the formation
  on its own bearing from the formation centre, so it keeps in range of the formation
  and clear of its positions (Sec. 6.2.2, "unassigned robots").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NavigationGains", "polar_control", "repulsion_magnitude", "repulsive_shift", "parking_point"]


@dataclass(frozen=True)
class NavigationGains:
    """Gains of (6.11)-(6.12)."""

    k_c: float = 1.0
    """Heading gain k_c of (6.11) [1/s]."""
    gamma: float = 0.5
    """gamma = |v_max| of (6.11) [m/s]."""
    k_r: float = 0.2
    """Repulsion gain k_r of (6.12) [m^3]."""
    R_max: float = 0.4
    """Influence distance R_max of the potential field [m]."""
    F_max: float = 5.0
    """Clip of the repulsive displacement F [m] (F grows like 1/R^3, docs/reference/derivations.md, repulsive target shift (D9)); only a
    numerical guard: (6.11) bounds the speed by gamma whatever the target distance."""
    side: float = 0.5
    """Sideways share of F when the obstacle lies ahead on the way to the goal."""


def polar_control(pose, goal, k_c: float, gamma: float, stop_radius: float = 0.0) -> tuple[float, float]:
    """Control law (6.11) for the polar error model (6.10).

    Parameters
    ----------
    pose : (3,) array_like
        Robot pose (x, y, theta).
    goal : (2,) array_like
        Target position (the final heading is not controlled).
    k_c, gamma : float
        Gains; |omega| <= k_c pi + gamma / 2.
    stop_radius : float
        Below this distance the command is zero (alpha is undefined at e = 0).

    Returns
    -------
    (v, omega) : tuple of float
    """
    x, y, th = (float(c) for c in np.asarray(pose, dtype=float).reshape(3))
    dx, dy = float(goal[0]) - x, float(goal[1]) - y
    e = math.hypot(dx, dy)
    if e <= stop_radius or e < 1e-9:
        return 0.0, 0.0
    alpha = math.atan2(math.sin(math.atan2(dy, dx) - th), math.cos(math.atan2(dy, dx) - th))
    th_e = math.tanh(e)
    v = gamma * th_e * math.cos(alpha)
    omega = k_c * alpha + gamma * (th_e / e) * math.sin(alpha) * math.cos(alpha)
    return v, omega


def repulsion_magnitude(R, k_r: float, R_max: float, F_max: float = math.inf):
    """F = k_r (1/R - 1/R_max) / R^2 for R < R_max, else 0 (6.12), clipped at F_max."""
    R = np.maximum(np.asarray(R, dtype=float), 1e-6)
    F = np.where(R < R_max, k_r * (1.0 / R - 1.0 / R_max) / R**2, 0.0)
    F = np.minimum(F, F_max)
    return float(F) if F.ndim == 0 else F


def repulsive_shift(p, goal, obstacles, gains: NavigationGains) -> np.ndarray:
    """New target (6.13)-(6.15): the goal displaced away from every obstacle within R_max.

    Parameters
    ----------
    p : (2,) array_like
        Robot position.
    goal : (2,) array_like
        Target position (x_d, y_d).
    obstacles : (n, 2) array_like
        Obstacle (other robot) positions.
    gains : NavigationGains

    Returns
    -------
    (2,) ndarray
        x_n = goal + sum_o F_o (p - p_o) / R_o, with, for an obstacle lying ahead on
        the way to the goal, an extra ``side * F_o`` to the right of the direction of
        travel, so two robots meeting head-on both keep right instead of stopping
        (the standstill of Sec. 6.2.2, where "the target position is changed").

    Notes
    -----
    (6.13)-(6.14) take |F cos(beta)| and |F sin(beta)| with the signs of (x - x_o) and
    (y - y_o), i.e. F along (p - p_o)/R with beta = atan2(y - y_o, x - x_o) (docs/reference/ambiguities.md,
    several obstacles in (6.12)-(6.15) (A25)); (6.15) adds the attraction (x_d - x), so x_n = x_d + F (p - p_o)/R.
    """
    p = np.asarray(p, dtype=float).reshape(2)
    g = np.asarray(goal, dtype=float).reshape(2)
    obs = np.asarray(obstacles, dtype=float).reshape(-1, 2)
    if len(obs) == 0:
        return g.copy()
    d = p - obs
    R = np.hypot(d[:, 0], d[:, 1])
    near = R < gains.R_max
    if not np.any(near):
        return g.copy()
    d, R = d[near], np.maximum(R[near], 1e-6)
    F = repulsion_magnitude(R, gains.k_r, gains.R_max, gains.F_max)
    u = d / R[:, None]  # (p - p_o)/R: direction of the repulsive force
    shift = np.sum(F[:, None] * u, axis=0)
    to_goal = g - p
    dist = math.hypot(*to_goal)
    if dist > 1e-6 and gains.side > 0:
        t = to_goal / dist
        right = np.array([t[1], -t[0]])
        ahead = (-u @ t) > 0.5  # obstacle within 60 deg of the direction to the goal
        shift += gains.side * np.sum(F[ahead]) * right
    return g + shift


def parking_point(p, centre, targets, clearance: float, avoid=()) -> np.ndarray:
    """Waiting place of a robot without a role: clear of every target, next to the formation.

    The point lies on the ray from the formation centre through the robot, beyond the
    farthest target along the ray and at the smallest radius beyond which the ray
    keeps ``clearance`` from every target (and from the waiting places in ``avoid``;
    when that fails the bearing is turned in 10 deg steps), so the robot stays within communication
    range of the formation's outer positions and out of the way of robots moving to
    their targets.

    Parameters
    ----------
    p : (2,) array_like
        Robot position (sets the bearing).
    centre : (2,) array_like
        Formation centre.
    targets : (M, 2) array_like
        Target positions to keep clear of.
    clearance : float
        Minimum distance to every target [m].
    avoid : (n, 2) array_like
        Other waiting places to keep ``clearance`` from (robots with priority).
    """
    c = np.asarray(centre, dtype=float).reshape(2)
    d = np.asarray(p, dtype=float).reshape(2) - c
    base = math.atan2(d[1], d[0]) if math.hypot(*d) > 1e-9 else 0.0
    pts = np.asarray(targets, dtype=float).reshape(-1, 2)
    av = np.asarray(avoid, dtype=float).reshape(-1, 2)
    allpts = np.vstack([pts, av]) if len(av) else pts
    # try the own bearing first, then bearings alternating left/right
    for k in range(0, 37):
        ang = base + (1 if k % 2 else -1) * ((k + 1) // 2) * math.radians(10.0)
        u = np.array([math.cos(ang), math.sin(ang)])
        rel = allpts - c
        along = rel @ u
        perp2 = np.sum(rel**2, axis=1) - along**2
        hit = perp2 < clearance**2
        rho = float(np.max(along[hit] + np.sqrt(clearance**2 - perp2[hit]))) if np.any(hit) else 0.0
        rho = max(rho, float(np.max(along[: len(pts)])) if len(pts) else 0.0)  # beyond the formation
        q = c + max(rho, 0.0) * u
        if len(av) == 0 or np.min(np.hypot(*(av - q).T)) >= clearance - 1e-9:
            return q
    return c + max(rho, 0.0) * u
