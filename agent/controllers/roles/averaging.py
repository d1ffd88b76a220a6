"""Consensus protocols of Chapter 6 (Sec. 2.3, (2.21); (6.16)).

- :func:`metropolis_weights` / :func:`metropolis_step`: the synchronous Metropolis
  iteration x_i <- x_i + sum_j (x_j - x_i) / (1 + max(|N_i|, |N_j|)) that reaches the
  exact average on any connected undirected graph without knowing N
  (docs/reference/ambiguities.md, average consensus with 1/|N_i| (A21): (2.21) with its 1/|N_i| weights conserves the degree-weighted sum, not
  the plain average).
- :class:`AverageConsensus`: the same iteration run by one robot over messages, in a
  mass-conserving edge-flow form that keeps the exact average under message delay,
  loss and a changing neighbour set (see its Notes).
- :class:`PIConsensus`: the proportional-integral dynamic consensus estimator (6.16)
  that tracks the time-varying average of w_i (fraction of unfinished robots).

Everything here is pure: numbers in, numbers out; no messages are built here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

__all__ = [
    "metropolis_weights",
    "metropolis_step",
    "metropolis_weight",
    "AverageConsensus",
    "NeighbourContribution",
    "PIConsensus",
]


def metropolis_weight(deg_i: int, deg_j: int) -> float:
    """Metropolis-Hastings edge weight 1 / (1 + max(|N_i|, |N_j|)) (docs/reference/ambiguities.md, average consensus with 1/|N_i| (A21))."""
    return 1.0 / (1.0 + max(int(deg_i), int(deg_j)))


def metropolis_weights(adjacency) -> np.ndarray:
    """Doubly stochastic Metropolis weight matrix W of an undirected graph.

    Parameters
    ----------
    adjacency : (N, N) array_like of bool
        Symmetric adjacency matrix (the diagonal is ignored).

    Returns
    -------
    W : (N, N) ndarray
        W_ij = 1 / (1 + max(d_i, d_j)) on edges, W_ii = 1 - sum_j W_ij; W is
        symmetric and rows sum to one, so 1^T x is conserved and x -> mean(x(0)) 1
        on a connected graph.
    """
    A = np.asarray(adjacency, dtype=bool).copy()
    np.fill_diagonal(A, False)
    if not np.array_equal(A, A.T):
        raise ValueError("adjacency must be symmetric (undirected graph)")
    deg = A.sum(axis=1)
    W = np.where(A, 1.0 / (1.0 + np.maximum(deg[:, None], deg[None, :])), 0.0)
    np.fill_diagonal(W, 1.0 - W.sum(axis=1))
    return W


def metropolis_step(x, adjacency) -> np.ndarray:
    """One synchronous Metropolis consensus step x <- W x for (N,) or (N, m) states."""
    return metropolis_weights(adjacency) @ np.asarray(x, dtype=float)


@dataclass(frozen=True)
class NeighbourContribution:
    """What robot i knows about neighbour j from j's latest message."""

    estimate: np.ndarray
    """(m,) j's current consensus estimate x_j."""
    degree: int
    """|N_j|: number of consensus neighbours j reported."""
    flow_to_me: np.ndarray
    """(m,) j's own cumulative contribution a_ji on the edge (j, i)."""
    echo: np.ndarray | None = None
    """(m,) the value of i's contribution a_ij that j had applied when it sent x_j (None:
    unknown, no correction)."""


@dataclass
class AverageConsensus:
    """Average consensus of one robot on an m-vector, by Metropolis steps in edge-flow form.

    The estimate is x_i = v_i - sum_j (a_ij - a_ji), where v_i is the robot's input,
    a_ij its own cumulative contribution on edge (i, j) and a_ji the latest value of
    the neighbour's contribution it received. Every step adds half a Metropolis
    increment to its own side of each edge::

        a_ij <- a_ij + (w_ij / 2) (x_i - x_j),   w_ij = 1 / (1 + max(|N_i|, |N_j|)).

    Notes
    -----
    Each message also echoes the neighbour's contribution as last received; the
    sender of x_j thus tells i which of i's own contributions x_j already contains, and
    i adds the ones still in flight before differencing. Without that correction the
    loop delay is a full round trip and the iteration goes unstable on sparse graphs
    once messages take three control periods or more (checked on a 10-robot chain).

    Synchronously and without loss the two halves add up to the Metropolis step
    x_i <- x_i + sum_j w_ij (x_j - x_i) (docs/reference/ambiguities.md, average consensus with 1/|N_i| (A21)). The flows are state, not
    increments, so a lost or late message only delays a flow; once both ends have
    heard each other's latest value sum_i x_i = sum_i v_i holds exactly, whatever the
    delays were. A neighbour that leaves keeps its (frozen) flows in the sum and a new
    one starts at zero, so a changing neighbour set never changes the average; only
    contributions still in flight when a link breaks for good are lost, and they are
    small once the estimates agree. No robot needs to know N.

    Parameters
    ----------
    value : (m,) array_like
        The robot's input v_i.
    gain : float
        Multiplier of the Metropolis step (1 = the Metropolis iteration).
    """

    value: np.ndarray
    gain: float = 1.0
    own: dict[str, np.ndarray] = field(default_factory=dict)
    """a_ij: own cumulative contribution per neighbour name."""
    theirs: dict[str, np.ndarray] = field(default_factory=dict)
    """a_ji: latest received contribution of each neighbour."""

    def __post_init__(self) -> None:
        self.value = np.array(self.value, dtype=float).reshape(-1)
        if not 0.0 < self.gain <= 2.0:
            raise ValueError(f"consensus gain must be in (0, 2], got {self.gain}")

    @property
    def estimate(self) -> np.ndarray:
        """Current estimate x_i of the network average (m,)."""
        x = self.value.copy()
        for j, a in self.own.items():
            x -= a - self.theirs.get(j, 0.0)
        for j, b in self.theirs.items():
            if j not in self.own:
                x += b
        return x

    def absorb(self, name: str, flow_to_me) -> None:
        """Record a neighbour's latest contribution a_ji without a consensus step (a
        message that arrived after the link broke still settles its flow)."""
        self.theirs[name] = np.asarray(flow_to_me, dtype=float).reshape(self.value.shape)

    def step(self, neighbours: Mapping[str, NeighbourContribution]) -> np.ndarray:
        """One consensus update with the neighbours heard (latest message each).

        Parameters
        ----------
        neighbours : mapping name -> NeighbourContribution
            Current consensus neighbours N_i; their count is |N_i|.

        Returns
        -------
        (m,) ndarray
            The updated estimate.
        """
        for j, c in neighbours.items():
            self.absorb(j, c.flow_to_me)
        x_i = self.estimate
        deg = len(neighbours)
        for j, c in neighbours.items():
            w = metropolis_weight(deg, c.degree)
            a = self.own.get(j, np.zeros_like(self.value))
            x_j = np.asarray(c.estimate, dtype=float)
            if c.echo is not None:
                # add what j will see of our contributions still in flight to it
                x_j = x_j + (a - np.asarray(c.echo, dtype=float).reshape(a.shape))
            self.own[j] = a + 0.5 * self.gain * w * (x_i - x_j)
        return self.estimate

    def echo_to(self, name: str) -> np.ndarray:
        """a_ji as last received from ``name`` (sent back so it can correct for its
        contributions in flight)."""
        return self.theirs.get(name, np.zeros_like(self.value))

    def flow_to(self, name: str) -> np.ndarray:
        """a_ij to send to neighbour ``name`` (zeros if it is new)."""
        return self.own.get(name, np.zeros_like(self.value))


@dataclass
class PIConsensus:
    """Proportional-integral dynamic consensus estimator (6.16) of one robot.

    Continuous form: z' = -k_P L z + k_z (w - z) + k_I L eta, eta' = -k_I L z, with
    L the Laplacian of the communication graph; z_i tracks the average of the inputs
    w_j (here w_i = 1 while robot i has not finished its task, 0 after).

    Notes
    -----
    (6.16) uses the unweighted Laplacian with unit gains. Its explicit Euler step is
    unstable once dt * lambda_max(L) > 2 (dense graphs at dt = 0.1 s), so the edges are
    weighted with the Metropolis weights (symmetric, lambda_max(L) < 2) and scaled by
    the gains k_P and k_I [1/s]; with k_P dt <= 1 the step is stable for any graph.
    Reset at a task switch (docs/reference/ambiguities.md, reset at a task switch (A26)): w = z = 1, eta = 0.

    Under communication delay the neighbours' z_j, eta_j are old; fed as they are, the
    coupling -k_P L z pulls every z_i back towards the team's past and the team's decay
    slows by a factor of about 1 + k_P deg tau. Each neighbour entry may carry its rates
    and age, (z_j, eta_j, deg_j, zdot_j, etadot_j, age_j): the values are then predicted
    to now, z_j + zdot_j age_j (docs/reference/envelope.md).
    """

    k_z: float
    """Forgetting factor [1/s]."""
    k_p: float = 5.0
    """Proportional (consensus) gain on the Metropolis Laplacian [1/s]."""
    k_i: float = 2.5
    """Integral gain on the Metropolis Laplacian [1/s]."""
    z: float = 1.0
    eta: float = 0.0
    zdot: float = 0.0
    """z-dot of the last step (sent with z for the neighbours' prediction)."""
    etadot: float = 0.0
    """eta-dot of the last step."""

    def reset(self, w: float = 1.0) -> None:
        """Start a new task: z = w, eta = 0 (docs/reference/ambiguities.md, reset at a task switch (A26))."""
        self.z = float(w)
        self.eta = 0.0
        self.zdot = self.etadot = 0.0

    def step(self, w: float, neighbours, dt: float) -> float:
        """One explicit Euler step of (6.16).

        Parameters
        ----------
        w : float
            Own input w_i (1 unfinished, 0 finished).
        neighbours : iterable of (z_j, eta_j, degree_j[, zdot_j, etadot_j, age_j])
            Latest values of the same-task neighbours; with rates and age they are
            predicted over the age of the message.
        dt : float
            Step [s].

        Returns
        -------
        float
            The new z_i.
        """
        nb = list(neighbours)
        deg = len(nb)
        lz = 0.0  # (L z)_i
        leta = 0.0  # (L eta)_i
        for z_j, eta_j, deg_j, *rates in nb:
            g = 1.0
            if len(rates) == 3:
                zdot_j, etadot_j, age = rates
                z_j, eta_j = z_j + zdot_j * age, eta_j + etadot_j * age
                g = min(1.0, 1.0 / (self.k_p * age)) if age > 0 else 1.0
            a = g * metropolis_weight(deg, deg_j)
            lz += a * (self.z - z_j)
            leta += a * (self.eta - eta_j)
        dz = -self.k_p * lz + self.k_z * (w - self.z) + self.k_i * leta
        deta = -self.k_i * lz
        self.z += dt * dz
        self.eta += dt * deta
        self.zdot, self.etadot = dz, deta
        return self.z
