"""``copath bench dmpc``: the achieved DMPC update period over Zenoh (Sec. 5.4).

For each fleet size (default 3, 8 and 16 omni robots) a temporary scenario is generated:
the robots spread evenly along the E5.2 ellipse (scaled so neighbours stay >= 0.8 m
apart), alternating lateral offsets q = +-0.4 m, a path graph 1-2-...-N, and the Sec. 5.4
controller. The fleet runs in ``realtime``: every robot is its own process on its own
timer of ``run.dt`` (default 0.05 s), exchanging assumed trajectories over Zenoh. From
the recorded log the benchmark prints, per fleet size, the achieved update period
(differences of consecutive controller step times, all robots pooled: p50/p99), the
controller step time (p50/p99), the deadline misses counted by the agents (a step that
ended after its next start time), the coordination error after settling and the start-up
time (call to the first tick: every robot built its controller and declared itself ready).

The dissertation's implementation reached an average update period of about 0.12 s
(E5.2) with three robots.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import time
from typing import Any

import numpy as np

from copath.paths import ellipse
from copath.scenario import parse_scenario

__all__ = ["add_arguments", "run", "scenario_table"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 8, 16], metavar="N",
                        help="fleet sizes to run [3 8 16]")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S", help="simulated seconds per run [20]")
    parser.add_argument("--dt", type=float, default=0.05, metavar="S", help="DMPC update period delta [0.05]")
    parser.add_argument("--horizon", type=int, default=10, help="prediction horizon N_p [10]")
    parser.add_argument("--settle", type=float, default=10.0, metavar="S",
                        help="coordination error measured after this time [10]")
    parser.add_argument("--out", help="keep the runs here (default: a temporary directory, removed)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


def scenario_table(n: int, dt: float, duration: float, horizon: int, settle: float) -> dict[str, Any]:
    """A DMPC scenario table with ``n`` robots evenly spread on a (scaled) E5.2 ellipse."""
    base = ellipse(1.5, 1.0)
    scale = max(1.0, 0.8 * n / base.length * 1.25)  # >= 0.8 m of path per robot, with margin
    a, b = 1.5 * scale, 1.0 * scale
    path = ellipse(a, b, rotation=math.pi / 6)
    spacing = path.length / n
    robots = []
    for i in range(n):
        name = f"r{i + 1}"
        q = 0.4 if i % 2 else -0.4
        s = (-i * spacing) % path.length
        x, y, th, _ = path.frame(s)
        pose = [x - q * math.sin(th) + 0.05, y + q * math.cos(th) - 0.05, th + 0.05]
        nbrs = [f"r{j + 1}" for j in (i - 1, i + 1) if 0 <= j < n]
        robots.append({"name": name, "model": "omni", "pose": [float(v) for v in pose], "path": "main",
                       "neighbours": nbrs, "controller": {"q": q}})
    return {
        "id": "e5.2",
        "title": f"DMPC update-period benchmark, {n} robots",
        "run": {"duration_s": duration, "dt": dt, "clock": "realtime", "settle_s": settle, "seed": n},
        "paths": {"main": {"type": "ellipse", "a": a, "b": b, "rotation": math.pi / 6}},
        "controller": {"type": "dmpc", "base_speed": 0.4, "horizon": horizon,
                       "formation": {f"r{i + 1}": -i * spacing for i in range(n)}},
        "robots": robots,
        "metrics": {"coordination_pairs": "edges"},
    }


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else math.nan


def _measure(n: int, args: argparse.Namespace, root: pathlib.Path) -> dict[str, Any]:
    from copath.wire.keys import Keys

    from orchestrator.studies.bench.fleet import _startup_s
    from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet
    from orchestrator.log.mcap import read_log
    from orchestrator.analysis.metrics import trace_from_records

    settle = min(args.settle, 0.5 * args.duration)
    scenario = parse_scenario(scenario_table(n, args.dt, args.duration, args.horizon, settle))
    run_id = new_run_id(f"bench-dmpc-{n}")
    t_call = time.time()
    t0 = time.monotonic()
    outcome = run_fleet(scenario, RunOptions(out_dir=root / run_id, run_id=run_id, progress=not args.quiet))
    wall = time.monotonic() - t0
    log = read_log(outcome.out_dir / "run.mcap")
    trace = trace_from_records(log.records, Keys(run_id))
    periods, steps, misses = [], 0, 0
    for name, rt in trace.robots.items():
        t = np.asarray(rt.telemetry_t, dtype=float)
        t = t[t >= 1.0]  # after start-up
        periods.append(np.diff(t))
        st = trace.stats.get(name, {})
        steps += int(st.get("steps", len(rt.telemetry_t)))
        misses += int(st.get("deadline_misses", 0))
    per = np.concatenate(periods) * 1e3 if periods else np.zeros(0)
    solve = np.concatenate([rt.solve_ms for rt in trace.robots.values()]) if trace.robots else np.zeros(0)
    m = outcome.metrics or {}
    return {
        "n": n,
        "ok": outcome.ok,
        "reason": outcome.reason,
        "period_p50": _pct(per, 50),
        "period_p99": _pct(per, 99),
        "step_p50": _pct(solve, 50),
        "step_p99": _pct(solve, 99),
        "steps": steps,
        "misses": misses,
        "coord": (m.get("fleet") or {}).get("coordination_error_max_m"),
        "failures": sum(int(r.get("solver_failures") or 0) for r in (m.get("robots") or {}).values()),
        "wall": wall,
        "startup_s": _startup_s(outcome.out_dir, t_call),
    }


def run(args: argparse.Namespace) -> int:
    """Run the benchmark and print one line per fleet size; 1 when a run failed."""
    from orchestrator.studies.bench.harness import emit, scratch_dir  # noqa: PLC0415

    with scratch_dir(args.out, "dmpc") as root:
        rows = [_measure(n, args, root) for n in args.robots]

    rows = [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()} for r in rows]
    emit(args, {"target_period_ms": args.dt * 1e3, "horizon": args.horizon, "duration_s": args.duration,
                "runs": rows, "kept_in": args.out}, lambda res: _table(res, args))
    return 0 if all(r["ok"] for r in rows) else 1


def _table(result: dict[str, Any], args: argparse.Namespace) -> None:
    rows = result["runs"]
    nan = float("nan")
    print(f"DMPC over Zenoh, realtime, target period {args.dt * 1e3:.0f} ms, horizon {args.horizon}, "
          f"{args.duration:.0f} s simulated per run")
    head = (f"{'robots':>6} {'period p50':>11} {'period p99':>11} {'step p50':>9} {'step p99':>9} "
            f"{'misses':>13} {'coord max m':>12} {'solver fail':>12} {'wall s':>7} {'startup s':>9}")
    print(head)
    print("-" * len(head))
    for r in rows:
        miss = f"{r['misses']}/{r['steps']}"
        coord = "-" if r["coord"] is None else f"{r['coord']:.4f}"
        g = {k: (nan if r[k] is None else r[k]) for k in ("period_p50", "period_p99", "step_p50", "step_p99")}
        print(f"{r['n']:>6} {g['period_p50']:>9.1f}ms {g['period_p99']:>9.1f}ms {g['step_p50']:>7.2f}ms "
              f"{g['step_p99']:>7.2f}ms {miss:>13} {coord:>12} {r['failures']:>12} {r['wall']:>7.1f} "
              f"{'-' if r['startup_s'] is None else format(r['startup_s'], '.1f'):>9}")
        if not r["ok"]:
            print(f"       run failed: {r['reason']}")
    if result["kept_in"]:
        print(f"runs kept in {result['kept_in']}")
