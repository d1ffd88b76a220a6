"""``copath bench fleet``: a scenario in lockstep over Zenoh and in one process, side by side.

For each scenario (default E5.4 and E6.1) it runs the fleet (one process per robot, the
simulator and the recorder, as ``copath run``) and the in-process loop (the same node
code on the in-memory bus, ``orchestrator/run/inprocess.py``) and prints the simulated time
each reached, the wall times, their real-time factors (simulated / wall) and the ratio of
the two. ``startup s`` is the fleet's time from the call to the first tick (every robot's
controller built, its liveliness token seen); ``fleet s`` is the whole fleet run, start-up
and the reading of the log included. ``agent CPU ms/step`` (from the agents' closing
accounts, p50 over agents, Zenoh's threads included), ``sim CPU s`` and ``inproc CPU
us/step`` (this process's CPU per robot step) are CPU times: on a shared machine they move
much less with the load than the wall times. Runs of scenarios with ``run.until = "tasks_done"``
end when their work is done.
"""

from __future__ import annotations

import argparse
import pathlib
import time
from typing import Any

from orchestrator.studies.bench.harness import emit, print_table, scratch_dir

__all__ = ["add_arguments", "run", "measure"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenarios", nargs="+", default=["e5.4", "e6.1"], metavar="SCENARIO",
                        help="bundled stems, experiment ids or files [e5.4 e6.1]")
    parser.add_argument("--duration", type=float, metavar="S", help="simulated seconds (default: the scenario's)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scenario value (TOML literal), as copath run --set; repeatable")
    parser.add_argument("--no-fleet", action="store_true", help="in-process only")
    parser.add_argument("--no-inprocess", action="store_true", help="fleet only")
    parser.add_argument("--out", help="keep the fleet runs here (default: a temporary directory, removed)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


def _startup_s(out: pathlib.Path, t_call: float) -> float | None:
    """Seconds from the call to the simulator's first tick (its ``Start`` record)."""
    from orchestrator.log.mcap import read_log  # noqa: PLC0415

    for _, _, rec in read_log(out / "run.mcap").records:
        if getattr(rec, "TYPE", "") == "start":
            return round(rec.wall_t0 - t_call, 3)
    return None


def _fleet_cpu(outcome, run_id: str) -> dict[str, Any]:
    """CPU of the fleet's processes from their closing accounts: the agents' CPU per control
    step from the start record on (Zenoh's threads included; p50 over agents) and the
    simulator's whole CPU time. CPU time depends much less on the machine's load than
    wall time, so before/after pairs compare on it (docs/journal/performance.md, profile of E5.4 (P12))."""
    from copath.wire.keys import Keys  # noqa: PLC0415

    from orchestrator.analysis.metrics import trace_from_records  # noqa: PLC0415

    if not outcome.records:
        return {"agent_cpu_ms_per_step": None, "sim_cpu_s": None}
    stats = trace_from_records(outcome.records, Keys(run_id)).stats
    per_step = sorted(1e3 * s["cpu_run_s"] / s["steps"] for p, s in stats.items()
                      if p != "sim" and s.get("cpu_run_s") is not None and s.get("steps"))
    return {"agent_cpu_ms_per_step": round(per_step[len(per_step) // 2], 3) if per_step else None,
            "sim_cpu_s": (stats.get("sim") or {}).get("cpu_s")}


def measure(name: str, args: argparse.Namespace, root: pathlib.Path) -> dict[str, Any]:
    from orchestrator import api  # noqa: PLC0415

    overrides = list(args.set) + ([f"run.duration_s={args.duration}"] if args.duration else [])
    if args.duration and api.load(name, list(args.set)).run.settle_s >= args.duration:  # errors after half the short run
        overrides.append(f"run.settle_s={0.5 * args.duration}")
    sc = api.load(name, overrides)
    row: dict[str, Any] = {"scenario": sc.id, "robots": len(sc.robots), "until": sc.run.until, "ok": True}
    if not args.no_inprocess:
        from orchestrator.run.inprocess import run_scenario  # noqa: PLC0415

        t0, c0 = time.perf_counter(), time.process_time()
        res = run_scenario(sc)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        steps = sum(1 for _, key, _ in res.records if key.endswith("/cmd"))
        row.update(inproc_sim_s=res.metrics["sim_time_s"], inproc_wall_s=round(wall, 3),
                   inproc_rtf=round(res.metrics["sim_time_s"] / wall, 2),
                   inproc_cpu_us_per_step=round(1e6 * cpu / steps, 1) if steps else None)
    if not args.no_fleet:
        from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet  # noqa: PLC0415

        rid = new_run_id(f"bench-{sc.id}")
        t_call = time.time()
        t0 = time.perf_counter()
        outcome = run_fleet(sc, RunOptions(out_dir=root / rid, run_id=rid, progress=False))
        wall = time.perf_counter() - t0
        m = outcome.metrics or {}
        start = _startup_s(outcome.out_dir, t_call)
        sim_t = m.get("sim_time_s") or 0.0
        row.update(_fleet_cpu(outcome, rid))
        row.update(ok=outcome.ok, reason=outcome.reason, fleet_sim_s=sim_t, fleet_wall_s=round(wall, 3),
                   startup_s=start, fleet_rtf=round(sim_t / wall, 2) if wall else None,
                   ticking_rtf=round(sim_t / (wall - start), 2) if start and wall > start else None)
    if row.get("inproc_rtf") and row.get("fleet_rtf"):
        row["ratio"] = round(row["inproc_rtf"] / row["fleet_rtf"], 2)
    return row


def _table(result: dict[str, Any]) -> None:
    print("lockstep runs: fleet over Zenoh (one process per robot) and the in-process loop; rtf = simulated / wall")
    print_table(result["runs"], [
        ("scenario", "scenario", ""), ("robots", "robots", "d"), ("until", "until", ""),
        ("fleet_sim_s", "sim s", ".1f"), ("startup_s", "startup s", ".2f"), ("fleet_wall_s", "fleet s", ".2f"),
        ("fleet_rtf", "fleet rtf", ".1f"), ("ticking_rtf", "rtf ticking", ".1f"),
        ("inproc_sim_s", "inproc sim s", ".1f"), ("inproc_wall_s", "inproc s", ".2f"),
        ("inproc_rtf", "inproc rtf", ".1f"), ("ratio", "inproc/fleet", ".1f"),
        ("agent_cpu_ms_per_step", "agent CPU ms/step", ".3f"), ("sim_cpu_s", "sim CPU s", ".2f"),
        ("inproc_cpu_us_per_step", "inproc CPU us/step", ".0f")])
    for r in result["runs"]:
        if not r["ok"]:
            print(f"{r['scenario']}: fleet run failed: {r.get('reason')}")


def run(args: argparse.Namespace) -> int:
    with scratch_dir(args.out, "fleet") as root:
        rows = [measure(s, args, root) for s in args.scenarios]
    emit(args, {"runs": rows}, _table)
    return 0 if all(r["ok"] for r in rows) else 1
