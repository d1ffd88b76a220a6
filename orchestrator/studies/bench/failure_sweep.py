"""The failure sweep (docs/reference/faults.md, "Does the fleet crash into itself?"): one robot at a
time killed, or its radio silenced to the end, at given times, in the bundled multi-robot
scenarios, each run in one process (lockstep, ``run.on_robot_failure = "continue"``), graded
from the simulator's truth.

    python -m orchestrator.studies.bench.failure_sweep [--only e5.1 e5.6-circle ...] [--faults kill silence]
                                       [--times 4 5 8 ...] [--victims r1 r4 ...]
                                       [--set run.cut_off=drive ...] [--json]

``--times`` and ``--victims`` replace the listed fault times and victims of every scenario run
(a grid over kill times: one kill time is not a measurement, docs/journal/detours.md, "A right
turn into a held robot"); a victim that is not a robot of a scenario is refused, naming it and
the scenario's robots.

Each run lasts its listed length, or :data:`AFTER_S` after the fault where that is longer.
Per run: collisions and minimum separation over the whole run (the metrics' rule), the
fleet's largest coordination error after settling over the live robots (docs/reference/metrics.md, formation error (M3)),
or the tasks completed (Chapter 6), and each live robot's progress along its path as a share
of its progress in the same run without the failure (``progress``; the goal of
docs/reference/detours.md is >= 90 % for every live robot), with the detours they made.
A kill is ``run_scenario(kills=...)``: the robot's link closes at that tick, as with
SIGKILL (its token goes, the simulator holds it still); a silence is ``network.silence``
from that time to the end.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any

from copath.scenario import Scenario, Silence
from copath.slots import track_coordinate
from orchestrator import api
from orchestrator.analysis.truth import truth_series
from orchestrator.run.inprocess import run_scenario
from orchestrator.studies.bench.harness import number
from orchestrator.testkit.scenarios import config

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
"""The sweep of docs/reference/faults.md ("Does the fleet crash into itself?"): 12 multi-robot
scenarios, up to two victims and two times each (chosen: early, and after the formation
settled, where the run is long enough)."""

AFTER_S = 50.0
"""Every run goes on at least this long after its fault [s] (chosen: the sweep measures whether
the live robots get round the lost one, so the run must outlast the pass; E5.4's column passes
its held robot within about 40 s of the kill, docs/journal/detours.md). A run whose listed
length is shorter is lengthened, and so is the run without the failure it is compared with."""


def run_length(duration_s: float, t_fault: float) -> float:
    """The length of a run with a fault at ``t_fault`` [s]: the listed one, or :data:`AFTER_S`
    after the fault where that is longer."""
    return max(float(duration_s), float(t_fault) + AFTER_S)


def progress(res, scen: Scenario) -> dict[str, float]:
    """How far each robot with a path truly got along it [m]: its path coordinate at the end
    less at the start (docs/reference/metrics.md, path coordinate of a true position (M1)), from the truth."""
    ser = truth_series(res.trace, scen)
    if ser is not None:
        S = ser.s
    else:
        S = {r.name: track_coordinate(scen.paths[r.path], res.trace.robots[r.name].pose[:, :2])
             for r in scen.robots if r.path and r.name in res.trace.robots}
    return {n: float(v[-1] - v[0]) for n, v in S.items() if len(v)}


def baseline(scen: Scenario, duration_s: float) -> dict[str, float]:
    """:func:`progress` of the same run without any failure."""
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"),
                               safety=dataclasses.replace(scen.safety, detours=True))
    return progress(run_scenario(scen, duration_s=duration_s, run_id="sweep-base"), scen)


def run_case(scen: Scenario, fault: str, victim: str, t_fault: float, duration_s: float,
             free: dict[str, float] | None = None) -> dict[str, Any]:
    """One run in one process with ``victim`` killed or silenced at ``t_fault``; ``free`` is
    :func:`baseline` (each live robot's progress is reported as a share of it)."""
    # the detour stage on ([safety] detours): the live robots go round the lost one (docs/reference/detours.md)
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"),
                               safety=dataclasses.replace(scen.safety, detours=True))
    if fault == "silence":
        scen = dataclasses.replace(scen, network=dataclasses.replace(
            scen.network, silence=(Silence(victim, t_fault, duration_s + 1.0),)))
    res = run_scenario(scen, duration_s=duration_s, run_id="sweep",
                       kills={victim: t_fault} if fault == "kill" else None)
    f = res.metrics["fleet"]
    share = None
    if free:
        got = progress(res, scen)
        share = {n: round(got[n] / free[n], 4) for n in got if n != victim and n in free and free[n] > 1e-6}
    return {"scenario": scen.id, "fault": fault, "robot": victim, "t_s": t_fault, "duration_s": duration_s,
            "collisions": f["collisions"], "min_separation_m": f["min_separation_m"],
            "coordination_error_max_m": f.get("coordination_error_max_m"),
            "tasks": None if f.get("tasks_total") is None else f"{f['tasks_completed']}/{f['tasks_total']}",
            "progress": share, "progress_min": min(share.values()) if share else None,
            "detours": sum(r.get("detours") or 0 for r in res.metrics["robots"].values())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="PREFIX", help="scenario prefixes of CASES to run")
    ap.add_argument("--faults", nargs="+", choices=("kill", "silence"), default=["kill", "silence"])
    ap.add_argument("--times", nargs="+", type=number("--times"), metavar="S",
                    help="fault times [s] instead of each scenario's listed ones")
    ap.add_argument("--victims", nargs="+", metavar="ROBOT", help="robots to fail instead of each scenario's listed ones")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run, e.g. run.cut_off=drive")
    ap.add_argument("--json", action="store_true", help="one JSON document instead of the table")
    args = ap.parse_args(argv)
    cases = [(api.load(config(prefix), overrides=args.set), tuple(args.times or times), duration,
              tuple(args.victims or victims))
             for prefix, times, duration, victims in CASES
             if not args.only or any(prefix.startswith(o) or o.startswith(prefix.rstrip("-")) for o in args.only)]
    for scen, _, _, victims in cases:  # refused before any run, not after the scenarios before it
        names = [r.name for r in scen.robots]
        unknown = [v for v in victims if v not in names]
        if unknown:
            ap.error(f"--victims {unknown[0]!r} is not allowed for {scen.id}; must be one of its robots: {', '.join(names)}")
    rows = []
    t0 = time.perf_counter()
    for scen, times, duration, victims in cases:
        free: dict[float, dict[str, float]] = {}  # run length -> progress without the failure
        for fault in args.faults:
            for victim in victims:
                for t in times:
                    length = run_length(duration, t)
                    if length not in free:
                        free[length] = baseline(scen, length)
                    row = run_case(scen, fault, victim, t, length, free[length])
                    rows.append(row)
                    if not args.json:
                        c, p = row["coordination_error_max_m"], row["progress_min"]
                        print(f"{row['scenario']:<42} {fault:<8} {victim:<7} {t:5.1f} s  collisions "
                              f"{row['collisions']:2d}  min sep {row['min_separation_m']:.3f} m  "
                              + (f"coord {c:.3f} m" if c is not None else f"tasks {row['tasks']}")
                              + (f"  progress >= {100 * p:.0f} %" if p is not None else "")
                              + f"  detours {row['detours']}", flush=True)
    hit = sum(r["collisions"] > 0 for r in rows)
    short = sum(r["progress_min"] is not None and r["progress_min"] < 0.9 for r in rows)
    if args.json:
        print(json.dumps({"runs": rows, "runs_with_contact": hit, "runs_below_90_percent_progress": short,
                          "wall_s": round(time.perf_counter() - t0, 1)}))
    else:
        print(f"{len(rows)} runs, {hit} with contact, {short} with a live robot below 90 % of its progress "
              f"without the failure, {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
