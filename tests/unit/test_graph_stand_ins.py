"""Stand-ins for a lost neighbour (copath/graph.py; docs/reference/faults.md, "Stand-ins for a
lost neighbour"): a robot listens, in place of a lost neighbour, to the live robots that
neighbour listened to, so the live graph stays connected."""

from __future__ import annotations

import itertools

from copath.graph import stand_ins

E54 = {"r1": ["r4", "r3"], "r2": ["r5"], "r3": ["r1", "r6"], "r4": ["r1"], "r5": ["r6", "r2"], "r6": ["r3", "r5"]}
"""E5.4's graph (configs/e5.4-six-robots-lemniscate.toml): the path r4 - r1 - r3 - r6 - r5 - r2."""
RING = {f"r{i}": [f"r{(i - 2) % 12 + 1}", f"r{i % 12 + 1}"] for i in range(1, 13)}
"""E5.6's circle swap: a ring of twelve."""


def test_a_lost_robot_s_neighbours_listen_to_each_other():
    assert stand_ins(E54, "r4", {"r1"}) == ("r3",)  # r4's only neighbour was r1
    assert stand_ins(E54, "r3", {"r1"}) == ("r4",)
    assert stand_ins(E54, "r6", {"r1"}) == ()  # not a neighbour of r1: nothing changes
    assert stand_ins(RING, "r12", {"r1"}) == ("r2",) and stand_ins(RING, "r2", {"r1"}) == ("r12",)


def test_a_chain_of_lost_robots_is_crossed_to_the_live_robots_at_its_far_end():
    assert stand_ins(E54, "r4", {"r1", "r3"}) == ("r6",)
    assert stand_ins(E54, "r4", {"r1", "r3", "r6", "r5"}) == ("r2",)
    assert stand_ins(RING, "r12", {"r1", "r2"}) == ("r3",)


def test_nothing_changes_without_a_lost_neighbour_or_for_a_robot_whose_neighbours_are_all_live():
    assert stand_ins(E54, "r4", set()) == ()
    assert stand_ins(E54, "r4", {"r2"}) == ()
    assert stand_ins(E54, "r1", {"r4"}) == ()  # r4 listened only to r1
    assert stand_ins(E54, "r9", {"r1"}) == ()  # a robot the graph does not name


def test_the_live_graph_stays_connected_whoever_is_lost():
    """Contracting the lost robots keeps every path between live ones: for every set of up to
    three lost robots of E5.4 and of the ring, the live robots with their own live neighbours and
    their stand-ins form one connected graph."""
    for graph in (E54, RING):
        names = sorted(graph)
        for k in (1, 2, 3):
            for lost in itertools.combinations(names, k):
                live = [n for n in names if n not in lost]
                edges = {n: {m for m in graph[n] if m not in lost} | set(stand_ins(graph, n, set(lost)))
                         for n in live}
                reached, todo = {live[0]}, [live[0]]
                while todo:
                    for m in edges[todo.pop()]:
                        if m not in reached:
                            reached.add(m)
                            todo.append(m)
                assert reached == set(live), (lost, reached)
