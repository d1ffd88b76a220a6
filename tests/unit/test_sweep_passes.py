"""The failure sweep's passes (orchestrator/studies/bench/failure_sweep.py, :func:`pass_spans`):
the stretches in which the live robots go round a lost one, after which their re-coordination
is graded (docs/reference/detours.md, the goal of 0.05 m within 20 s after the last has passed)."""

from __future__ import annotations

from copath.wire.messages import Event
from orchestrator.studies.bench.failure_sweep import pass_spans


def ev(t, robot, what):
    return Event(t, robot, what, {})


def test_overlapping_detours_of_several_robots_are_one_pass_and_each_lap_another():
    events = [ev(30.2, "r2", "detour_start"), ev(30.2, "r3", "detour_start"), ev(45.0, "r3", "detour_end"),
              ev(47.0, "r2", "detour_end"),  # r2 and r3 overlap: one pass, 30.2-47.0 s
              ev(64.7, "r3", "detour_start"), ev(70.1, "r3", "detour_end")]  # the next lap
    assert pass_spans(events, "r1", 30.0) == [[30.2, 47.0], [64.7, 70.1]]


def test_a_detour_under_way_at_the_end_leaves_its_pass_open():
    events = [ev(30.2, "r2", "detour_start"), ev(40.0, "r2", "detour_end"), ev(39.0, "r4", "detour_start")]
    assert pass_spans(events, "r1", 30.0) == [[30.2, None]]


def test_the_victim_s_own_detours_and_those_before_the_fault_are_not_passes():
    events = [ev(5.0, "r2", "detour_start"), ev(8.0, "r2", "detour_end"),  # before the fault at 10 s
              ev(12.0, "r1", "detour_start"), ev(13.0, "r1", "detour_end"),  # the victim's (a silenced robot)
              ev(20.0, "r3", "detour_start"), ev(21.0, "r3", "detour_end"),
              ev(22.0, "sim", "robot_lost")]  # other events are not detours
    assert pass_spans(events, "r1", 10.0) == [[20.0, 21.0]]
    assert pass_spans([], "r1", 10.0) == []
