"""Every ``copath bench`` subcommand runs briefly and prints its JSON document (no thresholds:
the figures themselves are measured by hand, orchestrator/studies/bench/README.md)."""

from __future__ import annotations

import json

import pytest

from orchestrator.cli import main as copath

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def _bench(capsys, *argv: str) -> dict:
    assert copath(["bench", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_bench_solve(capsys):
    out = _bench(capsys, "solve", "--controllers", "unicycle_nmpc", "--horizons", "5", "--solves", "20", "--warmup", "5")
    case = out["unicycle_nmpc"]["5"]
    assert case["solves"] == 20 and case["p50_ms"] > 0


def test_bench_dmpc(capsys):
    out = _bench(capsys, "dmpc", "--robots", "2", "--duration", "2", "--settle", "1", "-q")
    (row,) = out["runs"]
    assert row["n"] == 2 and row["ok"] and row["steps"] > 0
    assert out["machine"]["cores"] >= 1


def test_bench_fleet(capsys):
    out = _bench(capsys, "fleet", "--scenarios", "e5.5", "--duration", "2")
    (row,) = out["runs"]
    assert row["ok"] and row["fleet_sim_s"] == pytest.approx(2.0) and row["inproc_sim_s"] == pytest.approx(2.0)
    assert row["startup_s"] > 0 and row["fleet_rtf"] > 0 and row["inproc_rtf"] > 0


def test_bench_scale(capsys):
    out = _bench(capsys, "scale", "--robots", "3", "--duration", "2", "--settle", "1")
    (row,) = out["runs"]
    assert row["ok"] and row["robots"] == 3
    assert row["deadline_misses"] is not None and row["physics_overruns"] is not None
    assert 0 < row["peak_rss_mb_max"] < 1000


def test_bench_latency(capsys):
    out = _bench(capsys, "latency", "--robots", "3", "--duration", "2", "--messages", "2000")
    assert out["fleet"]["ok"] and out["fleet"]["age_ms_p50"] > 0
    assert [r["views"] for r in out["recorder"]] == [False, True]
    assert all(r["recorded"] + r["lost"] == 2000 for r in out["recorder"])
