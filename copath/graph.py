"""The communication graph round lost robots: who a robot listens to in place of a lost
neighbour (docs/reference/faults.md, "Stand-ins for a lost neighbour").

The dissertation's coordination laws couple each robot to its graph neighbours only: the
consensus (5.42) over the graph of Sec. 5.5, the distributed MPC's neighbour terms of (5.18).
They coordinate the team only while that graph is connected (Sec. 5.5.2). A robot that is
lost takes its edges with it, and a team whose graph is a path or a ring, as the bundled
columns and the circle swap are, falls apart into parts that nothing pulls together again
(E5.4 with r1 killed: r4's only neighbour was r1).

The repair kept here is the contraction of the lost robots: a robot listens, in place of a
lost neighbour, to the live robots that neighbour listened to, and through a chain of lost
robots to the live robots at its far end. Contracting nodes keeps every path between live
robots, so the live graph is connected whenever the whole graph was; and it needs nothing a
robot does not have: the scenario gives every robot the graph, and its liveness stage says
who is lost. Pure: no transport, no clock.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence

__all__ = ["stand_ins"]


def stand_ins(graph: Mapping[str, Sequence[str]], robot: str, lost: Collection[str]) -> tuple[str, ...]:
    """The live robots ``robot`` listens to in place of its lost neighbours: those reached from
    it through lost robots only (each lost robot's own neighbours, ``graph[name]``, the robots it
    listened to), less its own neighbours and itself; in the order they are reached, breadth
    first with each robot's neighbours in the graph's order (so every process finds the same).

    >>> column = {"r1": ["r2"], "r2": ["r1", "r3"], "r3": ["r2", "r4"], "r4": ["r3"]}
    >>> stand_ins(column, "r1", {"r2"})
    ('r3',)
    >>> stand_ins(column, "r1", {"r2", "r3"})
    ('r4',)
    >>> stand_ins(column, "r1", set())
    ()
    """
    own = graph.get(robot, ())
    if not lost or not any(n in lost for n in own):
        return ()
    out: list[str] = []
    seen = {robot, *own}
    frontier = [n for n in own if n in lost]
    visited = set(frontier)
    while frontier:
        nxt = []
        for gone in frontier:
            for n in graph.get(gone, ()):
                if n in lost:
                    if n not in visited:
                        visited.add(n)
                        nxt.append(n)
                elif n not in seen:
                    seen.add(n)
                    out.append(n)
        frontier = nxt
    return tuple(out)
