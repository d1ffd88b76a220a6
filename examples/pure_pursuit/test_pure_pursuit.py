"""The example controller, tested as a user would: in-process, then as a fleet of processes
over Zenoh started with ``copath run`` from this directory (the import path
``pure_pursuit:build`` resolves here, in the orchestrator and in every agent process)."""

from __future__ import annotations

import json
import os
import pathlib
import signal
import subprocess
import sys

import tomllib

import pytest

from orchestrator.run.inprocess import run_scenario
from orchestrator.run.validate import validate_file, validate_table

HERE = pathlib.Path(__file__).resolve().parent


def test_in_process_the_team_coordinates_without_collisions():
    m = run_scenario(validate_file(HERE / "scenario.toml")).metrics
    fleet = m["fleet"]
    assert fleet["collisions"] == 0
    assert fleet["coordination_error_max_m"] < 0.02  # from the truth, not from the controller
    assert max(r["path_error_max_m"] for r in m["robots"].values()) < 0.02


def test_graded_from_its_declared_geometry_as_with_typed_path_offsets():
    """The controller declares its team geometry: the truth figures are computed with no
    ``[metrics] path_offsets`` and are those the same offsets typed there give."""
    raw = tomllib.loads((HERE / "scenario.toml").read_text())
    assert "path_offsets" not in raw.get("metrics", {})
    declared = run_scenario(validate_file(HERE / "scenario.toml")).metrics["fleet"]
    typed = dict(raw, metrics={"path_offsets": {r["name"]: float(r.get("controller", {}).get("s_d", 0.0))
                                                for r in raw["robots"]}})
    given = run_scenario(validate_table(typed, base_dir=HERE)).metrics["fleet"]
    keys = [k for k in given if k.startswith(("coordination_error", "formation_error"))]
    computed = [k for k in keys if given[k] is not None]
    assert {"coordination_error_max_m", "formation_error_max_m"} <= set(computed)
    for k in keys:
        assert declared[k] == given[k], k


@pytest.mark.fleet
def test_copath_run_from_this_directory_runs_the_user_controller_as_a_fleet(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(HERE.parents[1]), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.Popen([sys.executable, "-m", "orchestrator", "run", "scenario.toml", "--out", str(out), "-q"],
                            cwd=HERE, env=env, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        stdout, stderr = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=10)
    assert proc.returncode == 0, stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["ok"] is True and m["scenario"] == "my-test"
    fleet = m["fleet"]
    assert fleet["messages_published"] == fleet["messages_recorded"] > 3000
    assert fleet["collisions"] == 0
    assert fleet["coordination_error_max_m"] < 0.02
    assert (out / "run.mcap").stat().st_size > 0
    assert sorted(m["robots"]) == ["r1", "r2", "r3"]
