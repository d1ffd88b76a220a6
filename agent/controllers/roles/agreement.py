"""Agreement on the team's translation and rotation (Algorithm 6.1): average consensus on
the moment vector (6.8)-(6.9) and the local test that ends it."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .averaging import AverageConsensus, NeighbourContribution
from .config import RolesConfig
from .peers import Peer
from .rotation import moment_vector

__all__ = ["Agreement", "N_MOMENTS"]


N_MOMENTS = 5
"""Size of the moment vector (6.8)-(6.9): x, y, x^2, xy, y^2."""


class Agreement:
    """Average consensus on the moment vector (Algorithm 6.1) and its local stop test.

    The robot adopts the estimate once neighbours' estimates and its own change over
    ``consensus_hold_s`` stay within ``consensus_tol`` (or after ``consensus_timeout_s``).

    A same-task neighbour stays a consensus neighbour while it was heard within the
    longer of ``neighbour_timeout_s`` and ``consensus_hold_s``: under loss a neighbour
    that drops out of the range-limited graph for a few silent steps and comes back
    would change every degree, hence every Metropolis weight, and stop the iteration
    each time (docs/reference/envelope.md). Its edge flow is state, so its newest one is used.
    """

    def __init__(self, name: str, p: np.ndarray, cfg: RolesConfig) -> None:
        self.name = name
        self.cfg = cfg
        self.ac = AverageConsensus(moment_vector(p), gain=cfg.consensus_gain)
        self.history: list[tuple[float, np.ndarray, float]] = []
        """(t, estimate, largest neighbour disagreement) over the hold window."""
        self.neighbours: dict[str, NeighbourContribution] = {}
        self.memory_s = max(cfg.neighbour_timeout_s, cfg.consensus_hold_s)
        """A neighbour counts while heard within this [s]."""
        self.heard: dict[str, Peer] = {}
        """Newest same-task state of every consensus neighbour."""

    def step(self, same: dict[str, Peer], t: float | None = None, lost: frozenset[str] = frozenset()) -> np.ndarray:
        """One consensus iteration over the neighbours' latest contributions; the estimate.
        A robot in ``lost`` leaves at once instead of after the memory (robot lost in role assignment, A38)."""
        self.heard.update(same)
        if t is not None:
            self.heard = {n: q for n, q in self.heard.items()
                          if n in same or (t - q.heard <= self.memory_s and n not in lost)}
        nbrs = {}
        for n, q in (self.heard if t is not None else same).items():
            x = q.payload.get("ac_x")
            if not x or len(x) != N_MOMENTS:
                continue
            to = q.payload.get("ac_to") or []
            flows = q.payload.get("ac_a") or []
            echoes = q.payload.get("ac_e") or []
            a = np.zeros(N_MOMENTS)
            echo = np.zeros(N_MOMENTS)  # it has not heard us yet: nothing of ours applied
            if self.name in to:
                k = to.index(self.name)
                a = np.asarray(flows[k * N_MOMENTS:(k + 1) * N_MOMENTS], dtype=float)
                if len(echoes) == len(flows):
                    echo = np.asarray(echoes[k * N_MOMENTS:(k + 1) * N_MOMENTS], dtype=float)
            nbrs[n] = NeighbourContribution(np.asarray(x, dtype=float), int(q.payload.get("ac_deg", 0)), a, echo)
        self.neighbours = nbrs
        return self.ac.step(nbrs)

    def settled(self, est: np.ndarray, t: float, task_start: float) -> tuple[bool, bool]:
        """(agreed, timed out) after recording this step's estimate."""
        cfg = self.cfg
        spread = max((float(np.max(np.abs(c.estimate - est))) for c in self.neighbours.values()), default=math.inf)
        self.history.append((t, est.copy(), spread))
        hold = cfg.consensus_hold_s
        window = [h for h in self.history if h[0] >= t - hold - 1e-9]
        self.history = window
        timed_out = t - task_start >= cfg.consensus_timeout_s
        agreed = (
            t - task_start >= hold
            and all(h[2] <= cfg.consensus_tol for h in window)
            and float(np.max(np.abs(window[0][1] - est))) <= cfg.consensus_tol
        )
        return agreed, timed_out

    def payload(self) -> dict[str, Any]:
        """The consensus fields of ``role_state`` (edge-flow form, see :class:`AverageConsensus`)."""
        to = sorted(self.neighbours)
        return {
            "ac_x": [float(c) for c in self.ac.estimate],
            "ac_to": to,
            "ac_a": [float(c) for n in to for c in self.ac.flow_to(n)],
            "ac_e": [float(c) for n in to for c in self.ac.echo_to(n)],
            "ac_deg": len(to),
        }
