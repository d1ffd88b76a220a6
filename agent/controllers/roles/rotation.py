"""Common rotation and translation of a target formation (Sec. 6.2.2, (6.3), (6.8)-(6.9),
Algorithm 6.1).

The robots agree on the centroid x_bar of their positions and on the angle theta_f of
their first principal axis; every robot then places template position k at (docs/reference/ambiguities.md,
rotation direction and order of translation (A22))::

    g_k = x_bar + R_ccw(theta_f - theta_tmpl) (x^d_k - x_bar^d)

with theta_tmpl and x_bar^d the template's own principal-axis angle and centroid.

Algorithm 6.1 runs the power method (6.8) through average consensus:
q(n) = AC(x_j (x_j . q(n-1))) / ||.||, with centred positions x_j. Because the average
is linear and q(n-1) is common to all robots (a deterministic shared q(0), docs/reference/ambiguities.md,
start vector and principal axis (A23)), AC(x_j x_j^T q) = AC(x_j x_j^T) q: one average consensus on the moment vector
m_j = (x, y, x^2, x y, y^2) gives every robot the covariance C = E[x x^T] - x_bar x_bar^T,
and the power iterations then need no further messages. :func:`principal_axis_ac`
runs the literal nested form (an inner consensus per power step) on a known graph as
a reference for tests.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from .averaging import metropolis_weights

__all__ = [
    "Q0",
    "moment_vector",
    "covariance_from_moments",
    "canonical_axis",
    "power_iteration",
    "principal_axis",
    "principal_axis_ac",
    "template_frame",
    "transform_targets",
]

logger = logging.getLogger(__name__)

Q0 = np.array([1.0, 0.3]) / math.hypot(1.0, 0.3)
"""Shared deterministic initial vector q(0) of the power method (docs/reference/ambiguities.md, start vector and principal axis (A23))."""


def moment_vector(p) -> np.ndarray:
    """Moment vector (x, y, x^2, x y, y^2) of a position, the input of the consensus."""
    x, y = (float(c) for c in np.asarray(p, dtype=float).reshape(2))
    return np.array([x, y, x * x, x * y, y * y])


def covariance_from_moments(m) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (2,) and covariance (2, 2) from averaged moments: C = E[x x^T] - x_bar x_bar^T."""
    m = np.asarray(m, dtype=float)
    c = m[:2]
    C = np.array([[m[2], m[3]], [m[3], m[4]]]) - np.outer(c, c)
    return c, 0.5 * (C + C.T)


def canonical_axis(q) -> np.ndarray:
    """Fix the eigenvector's sign (docs/reference/ambiguities.md, start vector and principal axis (A23)): q_x > 0, or q_y > 0 when q_x ~ 0."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q)
    if q[0] < -1e-9 or (abs(q[0]) <= 1e-9 and q[1] < 0):
        q = -q
    return q


def power_iteration(C, q0=Q0, eps: float = 1e-10, max_iter: int = 10000) -> tuple[np.ndarray, int]:
    """Power method (6.8): q(n+1) = C q(n) / ||C q(n)|| until ||q(n+1) - q(n)|| <= eps.

    Returns the canonical unit vector and the number of iterations. A zero product
    (C q = 0) returns q0 unchanged.
    """
    C = np.asarray(C, dtype=float)
    q = np.asarray(q0, dtype=float) / np.linalg.norm(q0)
    for n in range(1, max_iter + 1):
        y = C @ q
        ny = np.linalg.norm(y)
        if ny < 1e-15:
            return canonical_axis(q), n
        q_new = y / ny
        if np.linalg.norm(q_new - q) <= eps:
            return canonical_axis(q_new), n
        q = q_new
    return canonical_axis(q), max_iter


def principal_axis(C, isotropy: float = 1.2) -> float | None:
    """Angle of the first principal axis of covariance C, or None if nearly isotropic.

    Parameters
    ----------
    C : (2, 2) array_like
        Covariance of the positions.
    isotropy : float
        Fallback threshold: when lambda_1 < isotropy * lambda_2 the power method is
        ill-conditioned and the axis meaningless (robots on a circle, a square
        lattice), and None is returned; the caller then keeps the template's own
        orientation (docs/reference/controllers-notes.md, no principal axis for isotropic point sets (N8)).
    """
    C = np.asarray(C, dtype=float)
    lam = np.linalg.eigvalsh(C)  # ascending; only used for the conditioning test
    if lam[1] <= 1e-12 or lam[1] < isotropy * max(lam[0], 0.0):
        return None
    q, _ = power_iteration(C)
    return math.atan2(q[1], q[0])


def principal_axis_ac(points, adjacency, rounds: int = 200, eps: float = 1e-9, max_iter: int = 200):
    """Algorithm 6.1 literally, on a known graph, synchronously (reference for tests).

    Line 1-2: centroid by average consensus, positions centred. Lines 5-9: q(n) = AC of
    x_j (x_j . q_j(n-1)) with Metropolis consensus for ``rounds`` steps, normalised by
    each robot (the unknown 1/N cancels), until the change is below eps.

    Returns
    -------
    q : (N, 2) ndarray
        Each robot's canonical estimate of the first principal axis.
    """
    X = np.asarray(points, dtype=float)
    W = metropolis_weights(adjacency)
    Wr = np.linalg.matrix_power(W, rounds)
    xbar = Wr @ X  # each robot's consensus centroid
    Xc = X - xbar
    q = np.tile(Q0, (len(X), 1))
    for _ in range(max_iter):
        y = Xc * np.sum(Xc * q, axis=1, keepdims=True)  # x_j (x_j . q_j)
        y = Wr @ y
        q_new = y / np.linalg.norm(y, axis=1, keepdims=True)
        done = np.max(np.linalg.norm(q_new - q, axis=1)) <= eps
        q = q_new
        if done:
            break
    return np.array([canonical_axis(qi) for qi in q])


def template_frame(template, isotropy: float = 1.2) -> tuple[np.ndarray, float | None]:
    """Centroid x_bar^d and principal-axis angle theta_tmpl (None if isotropic) of a template."""
    T = np.asarray(template, dtype=float)
    c = T.mean(axis=0)
    C = (T - c).T @ (T - c) / len(T)
    return c, principal_axis(C, isotropy)


def transform_targets(template, centroid, rotation: float) -> np.ndarray:
    """Targets g_k = x_bar + R_ccw(rotation) (x^d_k - x_bar^d) (docs/reference/ambiguities.md, rotation direction and order of translation (A22)).

    Parameters
    ----------
    template : (M, 2) array_like
        Template positions x^d_k.
    centroid : (2,) array_like
        Agreed translation x_bar (the robots' consensus centroid).
    rotation : float
        Counter-clockwise rotation theta_f - theta_tmpl [rad] (0 keeps the template's
        orientation, as in E6.1).
    """
    T = np.asarray(template, dtype=float)
    c, s = math.cos(rotation), math.sin(rotation)
    R = np.array([[c, -s], [s, c]])
    return np.asarray(centroid, dtype=float) + (T - T.mean(axis=0)) @ R.T
