"""``copath bench scale``: realtime consensus fleets of growing size (Sec. 5.5 law).

For each fleet size N (default 8, 16, 32, 64, 128) a scenario is generated: N unicycles
evenly spread (0.6 m of path each) along an ellipse scaled to hold them, each with the
Lyapunov + second-order consensus law of Sec. 5.5 with E5.4's gains and a column
formation, on a chain graph 1-2-...-N. The fleet runs with the ``realtime`` clock: every
robot is its own process stepping on its own timer at 1/``--dt`` (default 10 Hz), the
simulator integrates every ``run.physics_dt`` = 10 ms on the wall clock.

Per size it prints the agents' deadline misses (a step that ended after the next period
began; and their share of all control periods), the simulator's physics overruns (steps
started late), the coordination error after ``--settle`` (from the truth; over all pairs,
and over the chain's edges only: on a chain the all-pairs figure adds up the small offsets
of its N - 1 edges, docs/journal/performance.md, realtime at 128 robots (P10)), the largest peak memory of an agent process, the start-up time (call to the first tick), the age of
neighbour messages on arrival (p99 over agents; from the sender's control instant, so
it includes the sender's step), the agents' CPU time per control step (median over agents,
from the start record on, Zenoh's threads included), the CPU cores the agents used
together, the simulator's CPU time and the wall time of the whole run.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import time
from typing import Any

from orchestrator.studies.bench.harness import emit, print_table, scratch_dir

__all__ = ["add_arguments", "run", "scenario_table"]

E54_GAINS = {"v0": 0.2, "k1": 5.0, "k2": 0.5, "k3": 0.2, "k4": 0.25, "k5": 1.0, "k6": 0.2,
             "theta_a": math.pi / 4, "sdot_max": 0.5}
"""E5.4's consensus gains (Sec. 5.5.3)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, nargs="+", default=[8, 16, 32, 64, 128], metavar="N",
                        help="fleet sizes [8 16 32 64 128]")
    parser.add_argument("--duration", type=float, default=30.0, metavar="S", help="simulated seconds per run [30]")
    parser.add_argument("--dt", type=float, default=0.1, metavar="S", help="control period [0.1 = 10 Hz]")
    parser.add_argument("--settle", type=float, default=20.0, metavar="S",
                        help="coordination error measured after this time [20]")
    parser.add_argument("--lease", type=float, default=5.0, metavar="S",
                        help="run.lease_s, the Zenoh transport lease [5]: with 1 s, a hundred processes on two "
                             "cores miss leases and their transports are reset (docs/journal/performance.md, realtime at 128 robots (P10))")
    parser.add_argument("--fork-server", action=argparse.BooleanOptionalAction, default=True,
                        help="start the agents by forking a pre-imported launcher (agent/zygote.py) [on]")
    parser.add_argument("--out", help="keep the runs here (default: a temporary directory, removed)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


def scenario_table(n: int, dt: float, duration: float, settle: float, spacing: float = 0.6,
                   lease: float = 1.0) -> dict[str, Any]:
    """A realtime consensus scenario with ``n`` unicycles in a column on a scaled ellipse."""
    from copath.paths import ellipse  # noqa: PLC0415

    base = ellipse(1.5, 1.0)
    scale = max(1.0, spacing * n * 1.1 / base.length)
    a, b = 1.5 * scale, 1.0 * scale
    path = ellipse(a, b)
    robots = []
    for i in range(n):
        s_d = -spacing * i
        x, y, th, _ = path.frame(s_d % path.length)
        robots.append({"name": f"r{i + 1}", "model": {"type": "unicycle", "v_max": 0.5, "omega_max": 1.0},
                       "pose": [x + 0.05, y - 0.05, th + 0.1], "path": "main",
                       "neighbours": [f"r{j + 1}" for j in (i - 1, i + 1) if 0 <= j < n],
                       "controller": {"s_d": s_d}})
    return {
        "id": "e5.4",
        "title": f"consensus scale benchmark, {n} robots",
        "run": {"duration_s": duration, "dt": dt, "clock": "realtime", "settle_s": min(settle, 0.5 * duration),
                "seed": n, "lease_s": lease},
        "paths": {"main": {"type": "ellipse", "a": a, "b": b}},
        "controller": {"type": "consensus", **E54_GAINS},
        "robots": robots,
    }


def _measure(n: int, args: argparse.Namespace, root: pathlib.Path) -> dict[str, Any]:
    from copath.scenario import parse_scenario  # noqa: PLC0415
    from copath.wire.keys import Keys  # noqa: PLC0415

    from orchestrator.studies.bench.fleet import _startup_s  # noqa: PLC0415
    from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet  # noqa: PLC0415
    from orchestrator.analysis.metrics import trace_from_records  # noqa: PLC0415

    table = scenario_table(n, args.dt, args.duration, args.settle, lease=args.lease)
    sc = parse_scenario(table)
    rid = new_run_id(f"bench-scale-{n}")
    t_call = time.time()
    t0 = time.perf_counter()
    outcome = run_fleet(sc, RunOptions(out_dir=root / rid, run_id=rid, progress=False, start_timeout_s=600.0,
                                            fork_server=args.fork_server))
    wall = time.perf_counter() - t0
    m = outcome.metrics or {}
    fleet = m.get("fleet") or {}
    stats = {}
    if (outcome.out_dir / "run.mcap").is_file():
        stats = trace_from_records(outcome.records, Keys(rid)).stats
    agents = [s for p, s in stats.items() if p != "sim"]
    rss = [s["peak_rss_mb"] for s in agents if s.get("peak_rss_mb") is not None]
    age99 = [s["peer_age_ms_p99"] for s in agents if s.get("peer_age_ms_p99") is not None]
    age50 = [s["peer_age_ms_p50"] for s in agents if s.get("peer_age_ms_p50") is not None]
    # CPU of the agents from the start record to their end, per control step (Zenoh's threads included)
    per_step = sorted(1e3 * s["cpu_run_s"] / s["steps"] for s in agents if s.get("cpu_run_s") is not None and s.get("steps"))
    run_cpu = sum(s["cpu_run_s"] for s in agents if s.get("cpu_run_s") is not None)
    sim_cpu = (stats.get("sim") or {}).get("cpu_s")
    edges = None  # the same run graded over the chain's edges only (neighbours), docs/reference/metrics.md, coordination error (M2)
    if (outcome.out_dir / "run.mcap").is_file():
        from orchestrator.log.mcap import read_log  # noqa: PLC0415
        from orchestrator.analysis.metrics import log_metrics  # noqa: PLC0415

        sc_edges = parse_scenario(dict(table, metrics={"coordination_pairs": "edges"}))
        m_edges = log_metrics(read_log(outcome.out_dir / "run.mcap"), sc_edges, run_id=rid, clock=sc.run.clock,
                              wall_time_s=wall, ok=outcome.ok, failure=outcome.reason)
        edges = (m_edges.get("fleet") or {}).get("coordination_error_max_m")
    return {
        "robots": n,
        "ok": outcome.ok,
        "reason": outcome.reason,
        "deadline_misses": fleet.get("deadline_misses"),
        "deadline_miss_rate": fleet.get("deadline_miss_rate"),
        "physics_overruns": fleet.get("physics_overruns"),
        "physics_steps": int(round(args.duration / sc.run.physics_dt)),
        "coordination_error_max_m": fleet.get("coordination_error_max_m"),
        "coordination_error_edges_max_m": edges,
        "peak_rss_mb_max": max(rss) if rss else None,
        "startup_s": _startup_s(outcome.out_dir, t_call) if (outcome.out_dir / "run.mcap").is_file() else None,
        "peer_age_ms_p50": round(sorted(age50)[len(age50) // 2], 3) if age50 else None,
        "peer_age_ms_p99_max": max(age99) if age99 else None,
        "agent_cpu_ms_per_step_p50": round(per_step[len(per_step) // 2], 3) if per_step else None,
        "agents_cpu_cores": round(run_cpu / args.duration, 3) if per_step else None,
        "sim_cpu_s": sim_cpu,
        "wall_s": round(wall, 2),
    }


def _table(result: dict[str, Any]) -> None:
    a = result["args"]
    print(f"realtime consensus fleets (Sec. 5.5), control at {1 / a['dt']:.0f} Hz, physics at 100 Hz, "
          f"{a['duration']:.0f} s simulated per run, transport lease {a['lease']:g} s")
    rows = [dict(r, miss_pct=None if r["deadline_miss_rate"] is None else 100 * r["deadline_miss_rate"]) for r in
            result["runs"]]
    print_table(rows, [
        ("robots", "robots", "d"), ("deadline_misses", "misses", "d"), ("miss_pct", "miss %", ".2f"),
        ("physics_overruns", "overruns", "d"), ("physics_steps", "of steps", "d"),
        ("coordination_error_max_m", "coord max m", ".4f"), ("coordination_error_edges_max_m", "edges max m", ".4f"), ("peak_rss_mb_max", "agent MB", ".0f"),
        ("startup_s", "startup s", ".1f"), ("peer_age_ms_p50", "age p50 ms", ".2f"),
        ("peer_age_ms_p99_max", "age p99 ms", ".2f"), ("agent_cpu_ms_per_step_p50", "agent CPU ms/step", ".2f"),
        ("agents_cpu_cores", "agents' cores", ".2f"), ("sim_cpu_s", "sim CPU s", ".1f"), ("wall_s", "wall s", ".1f")])
    for r in result["runs"]:
        if not r["ok"]:
            print(f"{r['robots']} robots: run failed: {r['reason']}")


def run(args: argparse.Namespace) -> int:
    with scratch_dir(args.out, "scale") as root:
        rows = [_measure(n, args, root) for n in args.robots]
    emit(args, {"args": {"dt": args.dt, "duration": args.duration, "settle": args.settle, "lease": args.lease},
                "runs": rows}, _table)
    return 0 if all(r["ok"] for r in rows) else 1
