"""``copath bench floor`` (orchestrator/studies/bench/floor.py) on a tiny case: the bare Zenoh
lockstep harness answers every tick in each receive mode, its recorder sees every sample,
its figures are positive and finite, and no process it started outlives it, a run that
times out included (no thresholds on speed: the figures are measured by hand,
docs/journal/performance.md, the floor of the design (P26))."""

from __future__ import annotations

import json
import math
import os
import subprocess

import pytest

from orchestrator.cli import main as copath
from orchestrator.studies.bench.floor import RECEIVE, ping

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.parametrize("receive", RECEIVE)
def test_ping_answers_every_tick_and_leaves_no_process(receive):
    pids: list[int] = []
    row = ping(robots=2, ticks=40, warmup=5, receive=receive, puts=2, overhear=True, timeout_s=120.0, started=pids)
    assert len(pids) == 3 and all(_gone(p) for p in pids)
    # every tick (2 robots) and every answer (2 records each) reached the recorder
    assert row["recorded"] == 45 * (2 + 2 * 2)
    for key in ("ticks_per_s", "tick_ms", "sim_cpu_ms_per_tick", "agent_cpu_ms_per_tick"):
        assert math.isfinite(row[key]) and row[key] > 0, (key, row)
    assert row["tick_ms"] == pytest.approx(1e3 / row["ticks_per_s"], rel=0.01)


def test_a_run_that_times_out_stops_its_processes():
    pids: list[int] = []
    with pytest.raises(subprocess.TimeoutExpired):
        ping(robots=2, ticks=10**7, warmup=5, timeout_s=3.0, started=pids)
    assert len(pids) == 3 and all(_gone(p) for p in pids)


def test_bench_floor_prints_its_json(capsys):
    assert copath(["bench", "floor", "--robots", "2", "--ticks", "30", "--warmup", "5", "--receive", "fifo",
                   "--no-irsim", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (row,) = out["ping"]
    assert row["receive"] == "fifo" and row["robots"] == 2 and row["ticks"] == 30 and row["over_irsim"] is None
    assert out["irsim"] is None and out["fleet"] == [] and out["machine"]["cores"] >= 1
