"""Chaos soak (issue 24; docs/reference/faults.md, "Chaos soak"): a fleet killed again and again under
``run.on_robot_failure = "restart"`` comes back every time, and its log says so.

The slow test is the issue's goal on E5.5 realtime over Zenoh: 2 minutes, 6 SIGKILLs on a
seeded schedule. The fast one is the same schedule in one process (lockstep, simulated
kills, each restarted a second later)."""

from __future__ import annotations

import os
import signal

import pytest

from orchestrator.studies.bench.chaos import HOLD_S, _cmdline, prepare, soak_fleet, soak_inprocess

pytestmark = [pytest.mark.faults]

SEED = 3
WARMUP_S = 10.0
"""The first kill's slot starts here (the schedule the bounds below were measured on; the
soak's default, E5.5's ``run.settle_s`` of 30 s, packs the six kills 12.5 s apart instead of
15.8 s, and the next kill then falls inside more of the windows)."""
COORD_WITHIN_S = 20.0
HELD_WITHIN_S = 45.0
"""Below 0.05 m for good (``recoord_held_s``) within this [s]: measured 11-40 s in one process
(a kill every 13-23 s; the next kill often falls inside the window), so the issue's 20 s holds
for the first instant only (docs/journal/faults.md, "First instant or for good"); this bound
catches a fleet that does not settle at all."""


def _kill_leftovers(run_id: str) -> None:
    """Every process of the run still alive (by pid, from /proc): none should be."""
    for d in os.listdir("/proc"):
        if d.isdigit() and int(d) != os.getpid() and run_id in _cmdline(d):
            try:
                os.kill(int(d), signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass


def _assert_goals(res: dict, target: float, restart_bound_s: float | None) -> None:
    rows, tot = res["faults"], res["totals"]
    assert len(rows) == 6 and all(r["kind"] == "kill" for r in rows)
    sent = [r for r in rows if not r["note"]]
    assert len(sent) >= 5, rows  # a victim still restarting when its next kill is due is skipped
    for r in sent:
        assert r["back_s"] is not None, r  # it commands again
        if restart_bound_s is not None:
            assert r["restart_to_cmd_s"] is not None and r["restart_to_cmd_s"] < restart_bound_s, r
        assert r["collisions"] == 0, r
        assert r["recoord_s"] is not None and r["recoord_s"] < COORD_WITHIN_S, r
        assert r["recoord_held_s"] is not None and r["recoord_held_s"] < HELD_WITHIN_S, r  # and stays
    graded = [r for r in rows if r.get("t_sim") is not None]
    cut = [r for r in graded if r["held_cut_by_next_fault"]]
    assert tot["held_cut_by_next_fault"] == len(cut)
    starts = sorted(r["t_sim"] for r in graded)
    for r in cut:  # held until the next fault began, which came within HOLD_S of that instant
        nxt = next(x for x in starts if x > r["t_sim"])
        assert nxt - (r["t_sim"] + (r["back_s"] or 0.0) + r["recoord_held_s"]) < HOLD_S + 0.5, r
    assert tot["collisions"] == 0
    assert tot["min_separation_m"] >= target
    assert tot["outage_open"] == [] and tot["ok"] is True, tot


@pytest.mark.slow
@pytest.mark.fleet
@pytest.mark.timeout(600)
def test_a_realtime_fleet_killed_six_times_comes_back_every_time(tmp_path):
    scen, faults = prepare("e5.5-", "realtime", "restart", 2.0, 6, SEED, kinds=("kill",), warmup_s=WARMUP_S)
    run_id = f"chaos-test-{os.getpid()}"
    try:
        res = soak_fleet(scen, faults, tmp_path, run_id=run_id)
    finally:
        _kill_leftovers(run_id)
    _assert_goals(res, scen.raw["targets"]["min_separation_m"], restart_bound_s=2.0)
    tot = res["totals"]
    assert tot["records_lost"] == 0  # no gap in any sender's sequence numbers
    assert tot["accounts_reconstructed"] == tot["faults_sent"]  # each killed process accounted for
    assert tot["messages_published"] == tot["messages_recorded"]
    assert tot["deadline_miss_rate"] is not None
    for r in res["faults"]:
        if not r["note"]:
            assert r["detect_s"] is not None and r["detect_s"] < 1.0, r  # a token goes within ms


def test_the_same_soak_in_one_process_comes_back_every_time():
    scen, faults = prepare("e5.5-", "lockstep", "restart", 2.0, 6, SEED, kinds=("kill",), warmup_s=WARMUP_S)
    res = soak_inprocess(scen, faults)
    _assert_goals(res, scen.raw["targets"]["min_separation_m"], restart_bound_s=None)
    # in one process a restart is a new node a second later: it commands at its first tick
    for r in res["faults"]:
        if not r["note"]:
            assert r["back_s"] == pytest.approx(1.0, abs=0.11), r
