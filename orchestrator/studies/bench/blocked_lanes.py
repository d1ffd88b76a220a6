"""The blocked-lane cases (docs/reference/detours.md, "Measured"): each bundled scenario with
something on its lanes run in one process (lockstep) beside the same run without it, graded
from the simulator's truth against the goals of docs/reference/detours.md.

    python -m orchestrator.studies.bench.blocked_lanes [--only PREFIX ...] [--set KEY=VALUE ...] [--json]

Per case: each live robot's progress along its path as a share of its progress without the
block (the obstacles removed, or the failure left out; the goal: >= 90 % for every live
robot), collisions and the smallest separation, the smallest clearance to an obstacle (> 0),
the detours and the longest stalled time, and how soon the live robots are back under 0.05 m
of coordination after the last of them has passed (the failure sweep's :func:`passes`, each
pass beside the run without the block from the same instant; the goal: within 20 s).
``--set safety.detours=false`` gives the same cases without the detour stage (the "before").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from typing import Any, NamedTuple

from copath.scenario import Scenario
from orchestrator import api
from orchestrator.analysis.truth import truth_series
from orchestrator.run.inprocess import run_scenario
from orchestrator.studies.bench.failure_sweep import (RECOORD_GOAL_S, Baseline, passes, progress,
                                                      worst_recoord)
from orchestrator.testkit.scenarios import config

PROGRESS_GOAL = 0.9
"""Every live robot makes at least this share of its progress without the block (docs/reference/detours.md)."""


class Case(NamedTuple):
    """One bundled blocked-lane case: the scenario and what blocks it (its obstacles, or a robot
    lost by its ``run.kills`` or ``network.silence``)."""

    prefix: str
    what: str


CASES = (
    Case("e5.5-column-box-on-lane", "Chapter 5 column (consensus), 0.2 m box on its lane, sensed"),
    Case("e5.2-dmpc-obstacle-between-lanes", "DMPC team, a known box between two robots' lanes"),
    Case("e5.7-heterogeneous-box-on-route", "heterogeneous leader-following team, box on its route, sensed"),
    Case("e5.4-six-robots-lemniscate-r1-killed", "E5.4 with r1 killed at 10 s"),
    Case("e5.4-six-robots-lemniscate-r1-lost", "E5.4 with r1's radio quiet from 10 s"),
)
"""The bundled cases of docs/reference/detours.md ("Measured")."""


def _fault(scen: Scenario) -> tuple[str, float]:
    """The lost robot and when it was lost, the first of the scenario's kills and silences ("" and
    0 for an obstacle)."""
    lost = [(k.at_s, k.robot) for k in scen.run.kills] + [(s.start_s, s.robot) for s in scen.network.silence]
    if not lost:
        return "", 0.0
    t, robot = min(lost)
    return robot, float(t)


def _without(scen: Scenario) -> Scenario:
    """The same scenario without its block: no obstacles, no kills and no silences."""
    return dataclasses.replace(scen, obstacles=(), run=dataclasses.replace(scen.run, kills=()),
                               network=dataclasses.replace(scen.network, silence=()))


def run_case(case: Case, scen: Scenario) -> dict[str, Any]:
    """The case and the same run without its block, graded from the truth."""
    duration = float(scen.run.duration_s)
    victim, t_fault = _fault(scen)
    base = Baseline.of(run_scenario(_without(scen), duration_s=duration, run_id="blocked-free"), scen)
    res = run_scenario(scen, duration_s=duration, run_id="blocked")
    ser = truth_series(res.trace, scen)
    passed = passes(res, scen, victim, t_fault, ser, base.coordination)
    share = base.shares(progress(res, scen, ser), victim)
    f, robots = res.metrics["fleet"], res.metrics["robots"]
    live = [n for n in robots if n != victim]
    row = {"scenario": scen.id, "what": case.what, "duration_s": duration,
           "lost": victim or None, "lost_at_s": t_fault if victim else None,
           "progress": share, "progress_min": min(share.values()) if share else None,
           "collisions": f["collisions"], "min_separation_m": f["min_separation_m"],
           "min_obstacle_clearance_m": f.get("min_obstacle_clearance_m"),
           "detours": sum(robots[n].get("detours") or 0 for n in live),
           "stalled_s_max": max((robots[n].get("stalled_s") or 0.0) for n in live),
           "passes": passed, "recoord_after_pass_max_s": worst_recoord(passed)}
    row["goals_met"] = goals_met(row)
    return row


def goals_met(row: dict[str, Any]) -> bool:
    """docs/reference/detours.md's goals: every live robot >= 90 % of its progress without the
    block, 0 collisions, obstacle clearance > 0, and back under 0.05 m within 20 s of the pass."""
    clear = row["min_obstacle_clearance_m"]
    recoord = row["recoord_after_pass_max_s"]
    return (row["progress_min"] is not None and row["progress_min"] >= PROGRESS_GOAL
            and row["collisions"] == 0 and (clear is None or clear > 0.0)
            and (row["passes"] is None or (recoord is not None and recoord <= RECOORD_GOAL_S)))


def _text(row: dict[str, Any]) -> str:
    clear = row["min_obstacle_clearance_m"]
    recoord = row["recoord_after_pass_max_s"]
    return (f"{row['scenario']:<38} progress >= {100 * row['progress_min']:5.1f} %  collisions {row['collisions']}  "
            f"min sep {row['min_separation_m']:.3f} m  clearance "
            + ("-" if clear is None else f"{clear:.3f} m")
            + f"  detours {row['detours']}  stalled <= {row['stalled_s_max']:.1f} s  recoord "
            + ("not graded" if row["passes"] is None else "never" if recoord is None else f"<= {recoord:.1f} s")
            + ("" if row["goals_met"] else "  GOAL MISSED"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="PREFIX", help="scenario prefixes of CASES to run")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run, e.g. safety.detours=false")
    ap.add_argument("--json", action="store_true", help="one JSON document instead of the table")
    args = ap.parse_args(argv)
    cases = [c for c in CASES if not args.only or any(c.prefix.startswith(o) for o in args.only)]
    if not cases:
        ap.error(f"--only {' '.join(args.only)!r} matches no case; allowed prefixes of: "
                 + ", ".join(c.prefix for c in CASES))
    t0 = time.perf_counter()
    rows = []
    for case in cases:
        row = run_case(case, api.load(config(case.prefix), overrides=args.set))
        rows.append(row)
        if not args.json:
            print(_text(row), flush=True)
    missed = sum(not r["goals_met"] for r in rows)
    if args.json:
        print(json.dumps({"cases": rows, "cases_missing_a_goal": missed, "wall_s": round(time.perf_counter() - t0, 1)}))
    else:
        print(f"{len(rows)} cases, {missed} missing a goal, {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
