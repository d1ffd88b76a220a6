"""orchestrator/studies/bench/blocked_lanes.py (docs/reference/detours.md, "Measured"): a bundled
blocked-lane case graded against the same run without its block, with and without the detour
stage; a prefix that names no case is refused."""

from __future__ import annotations

import json

import pytest

from orchestrator.studies.bench.blocked_lanes import main


def _cases(capsys, *args):
    assert main(["--json", *args]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_dmpc_team_goes_round_the_known_box_and_drives_through_it_without_the_stage(capsys):
    out = _cases(capsys, "--only", "e5.2-dmpc-obstacle")
    (row,) = out["cases"]
    assert row["scenario"] == "e5.2-dmpc-obstacle-between-lanes" and row["lost"] is None
    assert row["goals_met"] and out["cases_missing_a_goal"] == 0
    assert row["collisions"] == 0 and row["min_obstacle_clearance_m"] > 0.05  # 0.070 m measured
    assert set(row["progress"]) == {"r1", "r2", "r3"} and row["progress_min"] >= 0.9
    assert row["detours"] == 4  # r1 and r3 twice each (the box is between their lanes); r2's lane is free
    off = _cases(capsys, "--only", "e5.2-dmpc-obstacle", "--set", "safety.detours=false")["cases"][0]
    assert off["collisions"] > 0 and off["min_obstacle_clearance_m"] < 0 and off["detours"] == 0
    assert not off["goals_met"]


def test_e5_4_with_r1_killed_is_graded_over_the_live_robots_from_the_kill(capsys):
    (row,) = _cases(capsys, "--only", "e5.4-six-robots-lemniscate-r1-killed")["cases"]
    assert (row["lost"], row["lost_at_s"]) == ("r1", 10.0)
    assert set(row["progress"]) == {"r2", "r3", "r4", "r5", "r6"}  # r1 graded nowhere
    assert row["goals_met"] and row["collisions"] == 0 and row["progress_min"] >= 0.9
    assert row["recoord_after_pass_max_s"] is not None and row["recoord_after_pass_max_s"] <= 20.0
    assert all(p["recoord_without_failure_s"] == 0.0 for p in row["passes"] if p["end_s"] is not None)


def test_a_prefix_that_names_no_case_is_refused(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["--only", "e9"])
    assert refused.value.code == 2
    err = capsys.readouterr().err
    assert "--only 'e9' matches no case" in err and "e5.5-column-box-on-lane" in err
