"""When the truth completes a formation of Chapter 6: the occupancy rule, in one place.

A formation k is completed by the truth at the first tick at which the robots' true
positions occupy its target positions, one robot per target (every target when there are
at least as many robots as targets, Sec. 6.2.1; every robot on its own target otherwise),
each within a tolerance. The targets are the ones the team announced (the template after
the translation and rotation it agreed on, Algorithm 6.1); announced targets that are not a
rigid motion of the template do not count (docs/reference/metrics.md, tasks of Chapter 6 (M5)).

Two readers use it, so they cannot disagree: the metrics (``tasks_completed``,
``task_times_s``: every formation, over the whole log) and the simulator's stop rule
``run.until = "tasks_done"`` (the last formation, tick by tick, on the truth it owns;
:class:`LastFormationWatch`). The announced targets come from the robots' telemetry
(``formation_targets``): data, not a grade; whether they are occupied is decided here
from the truth only.

Which robots have a task queue, and what it holds, their controller family declares
(:attr:`copath.control.ControllerFactory.tasks`; the roles family reads its ``formations``
and ``arrive_tol``): this module never names a family.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

__all__ = [
    "ARRIVE_TOL_M",
    "TaskQueue",
    "queues_to_json",
    "queues_from_json",
    "formations",
    "task_tolerance",
    "rigid_residual",
    "is_rigid_placement",
    "occupied",
    "first_occupied",
    "LastFormationWatch",
]

ARRIVE_TOL_M = 0.05
"""Default tolerance of a target [m]: the roles controllers' ``arrive_tol`` default."""


@dataclass(frozen=True)
class TaskQueue:
    """One robot's Chapter 6 task queue, as its family declares it
    (:attr:`copath.control.ControllerFactory.tasks`): the robots with one are the ones this
    rule watches."""

    formations: tuple
    """The formation queue: template positions of each formation, in order."""
    arrive_tol: float = ARRIVE_TOL_M
    """The robot's own target tolerance [m]."""


def queues_to_json(queues: Mapping[str, TaskQueue]) -> str:
    """The robots' task queues as JSON text, {robot: {"formations": [...], "arrive_tol": m}}
    (handed to the simulator, which loads no controller family to ask)."""
    return json.dumps({n: {"formations": [[list(map(float, p)) for p in f] for f in q.formations],
                           "arrive_tol": q.arrive_tol} for n, q in queues.items()})


def queues_from_json(text: str) -> dict[str, TaskQueue]:
    """The task queues of :func:`queues_to_json` (raises ValueError naming what is wrong)."""
    try:
        raw = json.loads(text)
        return {str(n): TaskQueue(tuple(q["formations"]), float(q["arrive_tol"])) for n, q in raw.items()}
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise ValueError(f"task queues {text[:80]!r} are not allowed; expected JSON "
                         "{robot: {formations: [[[x, y], ...], ...], arrive_tol: m}}: " + str(exc)) from None


def formations(queues: Mapping[str, TaskQueue]) -> list:
    """The formation queue (templates) of the first robot with a task queue ([] without any);
    ``queues`` is {robot: its queue} in the scenario's robot order."""
    for q in queues.values():
        return list(q.formations or [])
    return []


def task_tolerance(scenario, names: Iterable[str], queues: Mapping[str, TaskQueue]) -> float:
    """``[metrics] task_tolerance_m``, else the first of ``names``' ``arrive_tol``."""
    tol = (getattr(scenario, "metrics", None) or {}).get("task_tolerance_m")
    if tol is not None:
        return float(tol)
    names = set(names)
    for n, q in queues.items():
        if n in names:
            return float(q.arrive_tol)
    return ARRIVE_TOL_M


def rigid_residual(template: np.ndarray, targets: np.ndarray) -> float:
    """Largest distance between ``targets`` and the best rigid motion (rotation and
    translation, Kabsch) of ``template`` onto them, point by point [m]."""
    if template.shape != targets.shape:
        return math.inf
    a, b = template - template.mean(axis=0), targets - targets.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    R = u @ np.diag([1.0, d]) @ vt
    return float(np.max(np.hypot(*(a @ R - b).T)))


def is_rigid_placement(template: Any, targets: Any) -> bool:
    """The announced ``targets`` are a rotation and translation of ``template`` (to 1e-6,
    relative to the template's size)."""
    T = np.asarray(template, dtype=float).reshape(-1, 2)
    G = np.asarray(targets, dtype=float).reshape(-1, 2)
    return rigid_residual(T, G) <= 1e-6 + 1e-6 * float(np.max(np.abs(T), initial=1.0))


def occupied(P: np.ndarray, G: np.ndarray, tol: float) -> bool:
    """Are the targets G (m, 2) occupied by the positions P (n, 2), one robot per target,
    within tol? Every target when n >= m, every robot otherwise (a matching, checked
    exactly by the Hungarian method)."""
    D = np.linalg.norm(P[:, None, :] - G[None, :, :], axis=-1)  # (n, m)
    near = D <= tol
    if not (near.any(axis=0).all() if len(P) >= len(G) else near.any(axis=1).all()):
        return False
    from scipy.optimize import linear_sum_assignment  # noqa: PLC0415 (rarely needed: keep start-up light)

    rows, cols = linear_sum_assignment(D)
    return bool(np.all(D[rows, cols] <= tol))


def first_occupied(P: np.ndarray, G: np.ndarray, tol: float) -> int | None:
    """Index of the first tick of P (T, n, 2) at which :func:`occupied` holds, else None."""
    D = np.linalg.norm(P[:, :, None, :] - G[None, None, :, :], axis=-1)  # (T, n, m)
    near = D <= tol
    cand = near.any(axis=1).all(axis=1) if P.shape[1] >= len(G) else near.any(axis=2).all(axis=1)
    from scipy.optimize import linear_sum_assignment  # noqa: PLC0415

    for k in np.nonzero(cand)[0]:
        rows, cols = linear_sum_assignment(D[k])
        if np.all(D[k][rows, cols] <= tol):
            return int(k)
    return None


class LastFormationWatch:
    """Online form of the rule for the last formation of the queue, for a stop rule.

    Feed it the robots' telemetry (:meth:`update`, any order within a tick) and ask
    :meth:`completed` with the true positions of the tick. The targets are those of the
    first robot to announce the last formation's ``formation_targets`` (earliest time;
    at equal times the first robot in ``names`` order), as in the metrics; targets that
    are not a rigid motion of the template are ignored, as there. The first tick checked
    is the announcement's: the metrics' window starts there too.

    Parameters
    ----------
    names : sequence of str
        The ``roles`` robots, in scenario order; :meth:`completed` takes their positions in
        this order.
    templates : sequence
        The formation queue (template positions of each formation).
    tol : float
        Target tolerance [m] (:func:`task_tolerance`).
    """

    def __init__(self, names: Sequence[str], templates: Sequence, tol: float) -> None:
        self.names = list(names)
        self._order = {n: i for i, n in enumerate(self.names)}
        self.last = len(templates) - 1
        self.template = np.asarray(templates[-1], dtype=float).reshape(-1, 2) if len(templates) else None
        self.tol = float(tol)
        self.announced: tuple[float, int, np.ndarray] | None = None
        """(time, robot order, targets) of the first announcement of the last formation."""
        self._rigid: bool | None = None
        """Whether the announced targets are a rigid placement (checked once per announcement)."""

    def update(self, name: str, t: float, data: Mapping[str, Any]) -> None:
        """One telemetry record of robot ``name`` stamped ``t``."""
        if self.last < 0 or name not in self._order or data.get("task") != self.last:
            return
        G = data.get("formation_targets")
        if G is None:
            return
        key = (float(t), self._order[name])
        if self.announced is None or key < self.announced[:2]:
            self.announced = (*key, np.asarray(G, dtype=float).reshape(-1, 2))
            self._rigid = None

    @property
    def targets(self) -> np.ndarray | None:
        """The announced targets of the last formation, if they are a rigid placement."""
        if self.announced is None:
            return None
        if self._rigid is None:
            self._rigid = is_rigid_placement(self.template, self.announced[2])
        return self.announced[2] if self._rigid else None

    def completed(self, t: float, P: np.ndarray) -> bool:
        """The true positions P (n, 2) of ``names`` at time t occupy the last formation."""
        G = self.targets
        if G is None or t < self.announced[0] - 1e-9:
            return False
        return occupied(np.asarray(P, dtype=float).reshape(-1, 2), G, self.tol)
