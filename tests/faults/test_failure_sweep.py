"""orchestrator/studies/bench/failure_sweep.py on one scenario: a killed robot is kept as a static disc and
passed without contact (docs/reference/safety.md, "A lost robot"); E5.5's r2 killed at 10 or 20 s was
driven into before (0.015 m)."""

from __future__ import annotations

import json

from orchestrator.studies.bench.failure_sweep import main


def test_the_sweep_kills_each_robot_and_the_column_never_touches_it(capsys):
    assert main(["--only", "e5.5", "--faults", "kill", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    runs = out["runs"]
    assert [(r["robot"], r["t_s"]) for r in runs] == [("r1", 10.0), ("r3", 10.0)]
    assert out["runs_with_contact"] == 0 and all(r["collisions"] == 0 for r in runs)
    assert all(r["scenario"] == "e5.5-column-lemniscate" and r["fault"] == "kill" for r in runs)
    # each live robot's progress against the same run without the failure (docs/reference/detours.md)
    for r in runs:
        assert set(r["progress"]) == {"r1", "r2", "r3"} - {r["robot"]}
        assert r["progress_min"] == min(r["progress"].values()) and 0.0 < r["progress_min"] < 1.5
