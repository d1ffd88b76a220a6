"""``copath bench peers`` (orchestrator/studies/bench/peers.py): IR-SIM's world file and the 16-robot
copath scenario it compares against; IR-SIM itself only where the ``peers`` extra is installed."""

from __future__ import annotations

import itertools
import math

import pytest

from orchestrator.studies.bench.peers import STEPS, e54_sixteen, irsim_world, run_irsim


def test_irsim_world_has_n_diff_drive_rvo_robots_and_the_step():
    yaml = pytest.importorskip("yaml")
    w = yaml.safe_load(irsim_world(16))
    assert w["world"]["step_time"] == 0.1
    (robots,) = w["robot"]
    assert robots["number"] == 16
    assert robots["kinematics"]["name"] == "diff" and robots["behavior"]["name"] == "rvo"
    assert "sensors" not in robots


def test_sixteen_robot_e54_is_a_column_on_one_lemniscate_with_e54s_law_and_filter():
    sc = e54_sixteen()
    assert len(sc.robots) == 16
    assert all(r.controller == "consensus" for r in sc.robots) and sc.safety.enabled
    assert sc.run.duration_s == 80.0 and sc.run.dt == 0.1
    ends = [r for r in sc.robots if len(r.neighbours) == 1]
    assert len(ends) == 2  # a chain
    poses = [r.pose for r in sc.robots]
    gap = min(math.hypot(a[0] - b[0], a[1] - b[1]) for a, b in itertools.combinations(poses, 2))
    assert gap > 2 * sc.robots[0].model.radius + 0.1


def test_irsim_runs_the_world_headless():
    pytest.importorskip("irsim")
    import pathlib
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        row = run_irsim(6, pathlib.Path(d), steps=20)
    assert row["irsim_sim_s"] == pytest.approx(2.0) and row["irsim_rtf"] > 0
    assert row["irsim_moving_at_end"] == 6  # 20 m to go at 0.25 m/s: nobody has arrived
    assert STEPS == 800
