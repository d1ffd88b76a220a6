"""The roles family's done rule: a robot's Chapter 6 task queue, for the occupancy rule of
:mod:`copath.occupancy` (``run.until = "tasks_done"`` and the task metrics,
docs/reference/metrics.md, tasks of Chapter 6 (M5))."""

from __future__ import annotations

from typing import Any, Mapping

from copath.occupancy import ARRIVE_TOL_M, TaskQueue

__all__ = ["task_queue"]


def task_queue(params: Mapping[str, Any]) -> TaskQueue:
    """The queue of formations in a robot's ``[controller]`` table and its ``arrive_tol``
    (read as given: the metrics grade what the scenario says, defaults included)."""
    return TaskQueue(tuple(params.get("formations") or ()), float(params.get("arrive_tol", ARRIVE_TOL_M)))
