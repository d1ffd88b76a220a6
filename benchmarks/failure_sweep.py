"""The failure sweep (docs/faults.md, "Does the fleet crash into itself?"): one robot at a
time killed, or its radio silenced to the end, at given times, in the bundled multi-robot
scenarios, each run in one process (lockstep, ``run.on_robot_failure = "continue"``), graded
from the simulator's truth.

    python benchmarks/failure_sweep.py [--only e5.1 e5.6-circle ...] [--faults kill silence]
                                       [--set run.cut_off=drive ...] [--json]

Per run: collisions and minimum separation over the whole run (the metrics' rule), and the
fleet's largest coordination error after settling, or the tasks completed (Chapter 6).
A kill is ``run_scenario(kills=...)``: the robot's link closes at that tick, as with
SIGKILL (its token goes, the simulator holds it still); a silence is ``network.silence``
from that time to the end.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time
from typing import Any

REPO = pathlib.Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from copath.scenario import Scenario, Silence  # noqa: E402
from orchestrator import api  # noqa: E402
from orchestrator.inprocess import run_scenario  # noqa: E402
from tests.conftest import config  # noqa: E402

CASES: list[tuple[str, tuple[float, ...], float, tuple[str, ...]]] = [
    # (scenario prefix, fault times [s], run length [s], victims)
    ("e5.1-", (8.0, 20.0), 45.0, ("f1", "leader")),
    ("e5.2-dmpc-five", (5.0, 15.0), 30.0, ("r1", "r3")),
    ("e5.3-", (5.0, 15.0), 30.0, ("r2",)),
    ("e5.4-", (10.0, 30.0), 60.0, ("r1", "r4")),
    ("e5.5-", (10.0,), 60.0, ("r1", "r3")),
    ("e5.6-circle", (5.0, 15.0), 40.0, ("r1", "r7")),
    ("e5.6-sinus", (10.0,), 40.0, ("r2",)),
    ("e5.7-", (10.0, 20.0), 40.0, ("r2", "r3")),
    ("e6.1-", (10.0, 30.0), 100.0, ("r3", "r9")),
    ("e6.3-", (5.0, 15.0), 60.0, ("r5",)),
    ("e6.5-", (5.0, 15.0), 60.0, ("r2", "r5")),
    ("e6.6-", (10.0, 20.0), 60.0, ("r2",)),
]
"""The sweep of docs/faults.md ("Does the fleet crash into itself?"): 12 multi-robot
scenarios, up to two victims and two times each (chosen: early, and after the formation
settled, where the run is long enough)."""


def run_case(scen: Scenario, fault: str, victim: str, t_fault: float, duration_s: float) -> dict[str, Any]:
    """One run in one process with ``victim`` killed or silenced at ``t_fault``."""
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"))
    if fault == "silence":
        scen = dataclasses.replace(scen, network=dataclasses.replace(
            scen.network, silence=(Silence(victim, t_fault, duration_s + 1.0),)))
    res = run_scenario(scen, duration_s=duration_s, run_id="sweep",
                       kills={victim: t_fault} if fault == "kill" else None)
    f = res.metrics["fleet"]
    return {"scenario": scen.id, "fault": fault, "robot": victim, "t_s": t_fault,
            "collisions": f["collisions"], "min_separation_m": f["min_separation_m"],
            "coordination_error_max_m": f.get("coordination_error_max_m"),
            "tasks": None if f.get("tasks_total") is None else f"{f['tasks_completed']}/{f['tasks_total']}"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="PREFIX", help="scenario prefixes of CASES to run")
    ap.add_argument("--faults", nargs="+", choices=("kill", "silence"), default=["kill", "silence"])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run, e.g. run.cut_off=drive")
    ap.add_argument("--json", action="store_true", help="one JSON document instead of the table")
    args = ap.parse_args(argv)
    rows = []
    t0 = time.perf_counter()
    for prefix, times, duration, victims in CASES:
        if args.only and not any(prefix.startswith(o) or o.startswith(prefix.rstrip("-")) for o in args.only):
            continue
        scen = api.load(config(prefix), overrides=args.set)
        for fault in args.faults:
            for victim in victims:
                for t in times:
                    row = run_case(scen, fault, victim, t, duration)
                    rows.append(row)
                    if not args.json:
                        c = row["coordination_error_max_m"]
                        print(f"{row['scenario']:<42} {fault:<8} {victim:<7} {t:5.1f} s  collisions "
                              f"{row['collisions']:2d}  min sep {row['min_separation_m']:.3f} m  "
                              + (f"coord {c:.3f} m" if c is not None else f"tasks {row['tasks']}"), flush=True)
    hit = sum(r["collisions"] > 0 for r in rows)
    if args.json:
        print(json.dumps({"runs": rows, "runs_with_contact": hit, "wall_s": round(time.perf_counter() - t0, 1)}))
    else:
        print(f"{len(rows)} runs, {hit} with contact, {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
