"""orchestrator/studies/bench/failure_sweep.py on one scenario: a killed robot is kept as a static disc and
passed without contact (docs/reference/safety.md, "A lost robot"); E5.5's r2 killed at 10 or 20 s was
driven into before (0.015 m)."""

from __future__ import annotations

import json

import pytest

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
    # re-coordination after the live robots have passed the lost one, from the truth: r1 killed
    # at 10 s is passed on two laps, each time back below 0.05 m at once; r3, last in the column,
    # is met only on the next lap, and that pass is still under way when the run ends
    first, last = runs
    assert [p["end_s"] is not None for p in first["passes"]] == [True, True]
    assert first["recoord_after_pass_max_s"] is not None and first["recoord_after_pass_max_s"] <= 20.0
    assert all(p["end_s"] is None and p["recoord_s"] is None for p in last["passes"])
    assert last["recoord_after_pass_max_s"] is None
    assert out["runs_not_recoordinated_within_20s_of_the_pass"] == 0 and out["runs_with_no_pass_to_grade"] == 1
    # each ended pass beside the run without the failure from the same instant: the column is
    # coordinated there, so at once; no slow pass, so no verdict on whose it is
    assert all(p["recoord_without_failure_s"] == 0.0 for p in first["passes"])
    assert all(r["recoord_slow_without_failure_too"] is None for r in runs)
    assert out["of_which_slow_without_the_failure_too"] == 0


def test_the_sweep_takes_its_own_times_and_victims_and_refuses_a_stranger(capsys):
    """``--times`` and ``--victims`` replace the listed ones (a grid over kill times); a victim
    that is not one of the scenario's robots is refused, naming it and the robots."""
    assert main(["--only", "e5.5", "--faults", "kill", "--times", "6", "--victims", "r2", "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)["runs"]
    assert [(r["robot"], r["t_s"], r["collisions"]) for r in runs] == [("r2", 6.0, 0)]
    assert set(runs[0]["progress"]) == {"r1", "r3"}
    with pytest.raises(SystemExit) as refused:  # refused before any run: E5.4 has r5, E5.5 has not
        main(["--only", "e5.4", "e5.5", "--victims", "r5"])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert "--victims 'r5' is not allowed for e5.5-column-lemniscate" in err and "r1, r2, r3" in err
    assert capsys.readouterr().out == ""
