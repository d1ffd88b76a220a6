"""Each chapter's controllers as real robot processes over Zenoh (lockstep unless said)."""

from __future__ import annotations

import json

import pytest

from copath.scenario import load_scenario
from orchestrator.cli import main as copath
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from tests.conftest import CONFIGS, config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(400)]


def _run(tmp_path, prefix, *extra):
    rc = copath(["run", str(config(prefix)), "--out", str(tmp_path), "-q", *extra])
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert rc == 0 and m["ok"], m.get("failure")
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]
    return m


def test_e4_2_omni_nmpc_path_following_over_zenoh(tmp_path):
    m = _run(tmp_path, "e4.2-", "--duration", "14")
    r = m["robots"]["r1"]
    assert r["path_error_max_m"] < 0.05 and r["heading_error_max_rad"] < 0.1
    assert r["limit_violations"] == 0 and r["wheel_speed_max_mps"] <= 1.9 + 1e-6
    assert r["solver_failures"] == 0
    # the process run is the in-process run: same solver, same inputs, same figures
    ref = run_scenario(load_scenario(config("e4.2-")), duration_s=14.0).metrics["robots"]["r1"]
    assert r["path_error_max_m"] == pytest.approx(ref["path_error_max_m"], abs=1e-6)


def test_e5_1_leader_following_with_delay_and_loss_over_zenoh(tmp_path):
    m = _run(tmp_path, "e5.1-", "--delay", "100", "--loss", "0.2")
    f = m["fleet"]
    assert f["messages_dropped_by_faults"] > 0
    assert f["coordination_error_max_m"] < 0.1 and f["collisions"] == 0
    assert f["formation_error_max_m"] < 0.1


def test_e5_2_distributed_mpc_over_zenoh(tmp_path):
    m = _run(tmp_path, "e5.2-", "--duration", "24", "--seed", "3")
    assert m["fleet"]["coordination_error_max_m"] < 0.02
    assert all(r["path_error_max_m"] < 0.05 and r["solver_failures"] == 0 for r in m["robots"].values())


def test_e6_5_role_assignment_with_faults_over_zenoh(tmp_path):
    m = _run(tmp_path, "e6.5-", "--delay", "100", "--loss", "0.1")
    f = m["fleet"]
    assert f["messages_dropped_by_faults"] > 0
    assert f["tasks_total"] == 3 and f["tasks_completed"] == 3
    assert f["collisions"] == 0 and f["min_separation_m"] > 0.12


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_e6_1_sixteen_robot_processes_with_faults(tmp_path):
    """16 robot processes spelling R-O-B-O-T (about 3-4 minutes on 2 cores): `python -m pytest -m slow`."""
    m = _run(tmp_path, "e6.1-", "--delay", "100", "--loss", "0.1", "--duration", "200")
    f = m["fleet"]
    assert f["tasks_completed"] == f["tasks_total"] == 5 and f["collisions"] == 0
    assert f["assignment_cost"] <= 1.1 * f["assignment_cost_optimal"]


@pytest.mark.slow
@pytest.mark.timeout(600)
@pytest.mark.parametrize("path", sorted(CONFIGS.glob("e*.toml")), ids=lambda p: p.stem)
def test_every_bundled_scenario_as_a_secure_fleet(tmp_path, path):
    """Each bundled scenario, full length, as a fleet behind a secure router (the default):
    every target met, nothing refused that a node needed (a refused subscription shows as
    a stalled or failed run), nothing rejected, every message recorded. About 4 minutes
    for all 24 on 2 cores: `python -m pytest -m slow -k secure_fleet`."""
    rc = copath(["run", str(path), "--out", str(tmp_path), "-q", "--no-plots", "--check"])
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"], m.get("failure")
    assert rc == 0  # --check: every target of the scenario's [targets] met
    f = m["fleet"]
    assert f["messages_rejected"] == 0 and f["messages_published"] == f["messages_recorded"]
    assert read_log(tmp_path / "run.mcap").metadata["copath"]["secure"] == "True"
