"""The failure sweep (docs/reference/faults.md, "Does the fleet crash into itself?"): one robot at a
time killed, or its radio silenced to the end, at given times, in the bundled multi-robot
scenarios, each run in one process (lockstep, ``run.on_robot_failure = "continue"``), graded
from the simulator's truth.

    python -m orchestrator.studies.bench.failure_sweep [--only e5.1 e5.6-circle ...] [--faults kill silence]
                                       [--times 4 5 8 ...] [--victims r1 r4 ...]
                                       [--set run.cut_off=drive ...] [--after S] [--json]

``--times`` and ``--victims`` replace the listed fault times and victims of every scenario run
(a grid over kill times: one kill time is not a measurement, docs/journal/detours.md, "A right
turn into a held robot"); a victim that is not a robot of a scenario is refused, naming it and
the scenario's robots.

Each run lasts its listed length, or :data:`AFTER_S` after the fault where that is longer
(``--after S`` instead: re-coordination is graded only for a pass that ended 20 s before the
run did, and a column that meets the lost robot a lap later needs longer runs).
Per run: collisions and minimum separation over the whole run (the metrics' rule), the
fleet's largest coordination error after settling over the live robots (docs/reference/metrics.md, formation error (M3)),
or the tasks completed (Chapter 6), and each live robot's progress along its path as a share
of its progress in the same run without the failure (``progress``; the goal of
docs/reference/detours.md is >= 90 % for every live robot), with the detours they made,
and how soon the live robots are back in coordination after they have passed the lost one
(:func:`passes`: the same goal's "below 0.05 m within 20 s after the last robot has passed"),
beside how soon the run without the failure is, from the same instant (a team slow to
re-coordinate unfailed is counted apart: the goal is not one a detour can meet there).
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
from typing import Any, NamedTuple

import numpy as np

from copath.scenario import Scenario, Silence
from copath.slots import track_coordinate
from orchestrator import api
from orchestrator.analysis.truth import truth_series
from orchestrator.run.inprocess import run_scenario
from orchestrator.studies.bench.chaos import held_below
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


RECOORD_GOAL_S = 20.0
"""The issue's goal: the live robots are back in coordination this soon after the last of them
has passed the lost one [s] (docs/reference/detours.md)."""


def run_length(duration_s: float, t_fault: float, after_s: float = AFTER_S) -> float:
    """The length of a run with a fault at ``t_fault`` [s]: the listed one, or ``after_s``
    (:data:`AFTER_S`) after the fault where that is longer."""
    return max(float(duration_s), float(t_fault) + after_s)


def progress(res, scen: Scenario, ser=None) -> dict[str, float]:
    """How far each robot with a path truly got along it [m]: its path coordinate at the end
    less at the start (docs/reference/metrics.md, path coordinate of a true position (M1)), from the truth."""
    ser = ser if ser is not None else truth_series(res.trace, scen)
    if ser is not None:
        S = ser.s
    else:
        S = {r.name: track_coordinate(scen.paths[r.path], res.trace.robots[r.name].pose[:, :2])
             for r in scen.robots if r.path and r.name in res.trace.robots}
    return {n: float(v[-1] - v[0]) for n, v in S.items() if len(v)}


def pass_spans(events, victim: str, t_fault: float) -> list[list[float | None]]:
    """The passes of :func:`passes`: [start, end] of each stretch of time in which a live robot
    (not ``victim``) was on a detour begun at or after ``t_fault`` [s], overlapping detours
    merged; end None while one was still under way when the log ended."""
    spans: list[list[float | None]] = []  # [start, end] per detour
    under_way: dict[str, list[float | None]] = {}
    for e in sorted(events, key=lambda e: e.t):
        if e.source == victim or e.t < t_fault - 1e-9:
            continue
        if e.what == "detour_start":
            under_way[e.source] = [float(e.t), None]
            spans.append(under_way[e.source])
        elif e.what == "detour_end" and e.source in under_way:
            under_way.pop(e.source)[1] = float(e.t)
    merged: list[list[float | None]] = []
    for a, b in sorted(spans, key=lambda sp: sp[0]):
        last = merged[-1] if merged else None
        if last is not None and (last[1] is None or a <= last[1] + 1e-9):
            last[1] = None if last[1] is None or b is None else max(last[1], b)
        else:
            merged.append([a, b])
    return merged


def passes(res, scen: Scenario, victim: str, t_fault: float, ser=None,
           free_coord: tuple[np.ndarray, np.ndarray] | None = None) -> list[dict[str, Any]] | None:
    """The live robots' passes of the lost one and their re-coordination after each, from the
    log: a pass is a stretch of time in which some live robot is on a detour begun after the
    fault (``detour_start`` to ``detour_end`` events, docs/reference/detours.md; overlapping
    detours of several robots are one pass, and the column going round a held robot on every lap
    makes one pass per lap). Per pass: when its last detour ended (``end_s``, None if one was
    still under way at the run's end) and the seconds from then until the coordination error
    among the live robots (from the truth, docs/reference/metrics.md, coordination error (M2)) is below
    :data:`~orchestrator.studies.bench.chaos.COORD_TOL_M` and stays there for
    :data:`~orchestrator.studies.bench.chaos.HOLD_S`, or until the next pass begins, or to the
    run's end (``recoord_s``; None: never), and how long that was (``window_s``: a pass that
    ended less than :data:`RECOORD_GOAL_S` before the next one or the run's end, and is not
    back yet, cannot be graded). Without a detour the fault itself is the pass.
    None where the family grades no coordination (Chapter 6 role teams). ``ser``: the run's
    truth series when the caller has it already. ``free_coord``: (t, coordination error) of the
    same run without the failure (:class:`Baseline`); each pass then also says how long that
    run took from the same instant (``recoord_without_failure_s``, the same rule): a scenario
    whose own team is not back within :data:`RECOORD_GOAL_S` of that instant (the circle swap
    after its crossing) misses the goal whatever the detours do."""
    ser = ser if ser is not None else truth_series(res.trace, scen)
    if ser is None or ser.coordination_error is None:
        return None
    episodes = pass_spans(res.trace.events, victim, t_fault)
    if not episodes:
        episodes = [[t_fault, t_fault]]
    out = []
    for k, (_, end) in enumerate(episodes):
        nxt = episodes[k + 1][0] if k + 1 < len(episodes) else None
        window = None if end is None else float((ser.t[-1] if nxt is None else nxt) - end)
        # a team back only after the next pass began is that pass's to grade (later=False)
        row = {"end_s": None if end is None else round(end, 2),
               "recoord_s": None if end is None else held_below(ser.t, ser.coordination_error, end, nxt, later=False),
               "window_s": None if window is None else round(window, 2)}
        if free_coord is not None:
            row["recoord_without_failure_s"] = None if end is None else held_below(*free_coord, end, nxt, later=False)
        out.append(row)
    return out


class Baseline(NamedTuple):
    """The same run without any failure: each robot's :func:`progress` [m] and the team's
    coordination error over time from the truth (``t``, ``coord``; None where the family grades
    no coordination)."""

    progress: dict[str, float]
    t: np.ndarray | None = None
    coord: np.ndarray | None = None

    @classmethod
    def of(cls, res, scen: Scenario) -> "Baseline":
        """The baseline of a finished run ``res`` of ``scen``."""
        ser = truth_series(res.trace, scen)
        if ser is None or ser.coordination_error is None:
            return cls(progress(res, scen, ser))
        return cls(progress(res, scen, ser), np.asarray(ser.t), np.asarray(ser.coordination_error))

    @property
    def coordination(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(t, coordination error) for :func:`passes`, None where not graded."""
        return None if self.coord is None else (self.t, self.coord)

    def shares(self, got: dict[str, float], lost: str) -> dict[str, float]:
        """Each live robot's progress ``got`` [m] as a share of its progress here (``lost``: the
        robot left out)."""
        base = self.progress
        return {n: round(got[n] / base[n], 4) for n in got if n != lost and n in base and base[n] > 1e-6}


def baseline(scen: Scenario, duration_s: float) -> Baseline:
    """The run of ``scen`` without any failure (:class:`Baseline`), with the sweep's settings."""
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"),
                               safety=dataclasses.replace(scen.safety, detours=True))
    return Baseline.of(run_scenario(scen, duration_s=duration_s, run_id="sweep-base"), scen)


def run_case(scen: Scenario, fault: str, victim: str, t_fault: float, duration_s: float,
             free: Baseline | None = None) -> dict[str, Any]:
    """One run in one process with ``victim`` killed or silenced at ``t_fault``; ``free`` is
    :func:`baseline` (each live robot's progress is reported as a share of it, and each pass's
    re-coordination beside that run's from the same instant)."""
    # the detour stage on ([safety] detours): the live robots go round the lost one (docs/reference/detours.md)
    scen = dataclasses.replace(scen, run=dataclasses.replace(scen.run, on_robot_failure="continue"),
                               safety=dataclasses.replace(scen.safety, detours=True))
    if fault == "silence":
        scen = dataclasses.replace(scen, network=dataclasses.replace(
            scen.network, silence=(Silence(victim, t_fault, duration_s + 1.0),)))
    res = run_scenario(scen, duration_s=duration_s, run_id="sweep",
                       kills={victim: t_fault} if fault == "kill" else None)
    f = res.metrics["fleet"]
    ser = truth_series(res.trace, scen)  # once for both
    passed = passes(res, scen, victim, t_fault, ser, None if free is None else free.coordination)
    share = None if free is None else free.shares(progress(res, scen, ser), victim)
    return {"scenario": scen.id, "fault": fault, "robot": victim, "t_s": t_fault, "duration_s": duration_s,
            "collisions": f["collisions"], "min_separation_m": f["min_separation_m"],
            "coordination_error_max_m": f.get("coordination_error_max_m"),
            "tasks": None if f.get("tasks_total") is None else f"{f['tasks_completed']}/{f['tasks_total']}",
            "progress": share, "progress_min": min(share.values()) if share else None,
            "detours": sum(r.get("detours") or 0 for r in res.metrics["robots"].values()),
            "passes": passed, "recoord_after_pass_max_s": worst_recoord(passed),
            "recoord_slow_without_failure_too": slow_without_failure(passed)}


def worst_recoord(passed: list[dict[str, Any]] | None) -> float | None:
    """The slowest re-coordination over the passes that ended [s]; None where coordination is
    not graded, where no pass ended (the live robots never got past) or where one never
    re-coordinated: a run that does not meet the goal is not given a figure that looks like one.
    A pass still under way at the run's end (the next lap's, in a column that goes round a held
    robot on every lap), or one that ended too close to it (:func:`graded`), is left out."""
    ended = [p for p in (passed or ()) if graded(p)]
    if not ended or any(p["recoord_s"] is None for p in ended):
        return None
    return max(p["recoord_s"] for p in ended)


def slow_without_failure(passed: list[dict[str, Any]] | None) -> bool | None:
    """Whether every graded pass that missed :data:`RECOORD_GOAL_S` missed it in the same run
    without the failure too, from the same instant (its team not back under 0.05 m within 20 s
    of when the pass ended: the scenario's own coordination, not the failure, is what is slow).
    None where no pass missed the goal or the run without the failure was not compared."""
    slow = [p for p in (passed or ()) if graded(p) and (p["recoord_s"] is None or p["recoord_s"] > RECOORD_GOAL_S)]
    if not slow or any("recoord_without_failure_s" not in p for p in slow):
        return None
    return all(p["recoord_without_failure_s"] is None or p["recoord_without_failure_s"] > RECOORD_GOAL_S
               for p in slow)


def graded(p: dict[str, Any]) -> bool:
    """A pass that can be graded: it ended, and it re-coordinated or had :data:`RECOORD_GOAL_S`
    to do so before the next pass or the run's end."""
    return p["end_s"] is not None and (p["recoord_s"] is not None or p["window_s"] >= RECOORD_GOAL_S - 1e-9)


def _slow_recoord(row: dict[str, Any]) -> bool:
    """The run misses the goal of re-coordinating within 20 s after the live robots have passed
    (graded once a pass has ended: :func:`_unpassed` counts the others)."""
    return not _unpassed(row) and row["passes"] is not None and (
        row["recoord_after_pass_max_s"] is None or row["recoord_after_pass_max_s"] > RECOORD_GOAL_S)


def _unpassed(row: dict[str, Any]) -> bool:
    """Coordination is graded but no pass can be: none ended, or none ended long enough before
    the run did and re-coordinated (a run too short for the goal, or robots stuck at the lost
    one; their progress says which)."""
    return row["passes"] is not None and not any(graded(p) for p in row["passes"])


def _recoord_text(row: dict[str, Any]) -> str:
    """The table's re-coordination column: the slowest pass, or why there is no figure."""
    if row["passes"] is None:
        return ""
    n = len(row["passes"])
    if row["recoord_after_pass_max_s"] is None:
        if any(graded(p) for p in row["passes"]):
            return f"  passes {n}  recoord never"
        ended = any(p["end_s"] is not None for p in row["passes"])
        return f"  passes {n}  recoord " + ("not graded: the run ended within 20 s of the pass" if ended
                                            else "not graded: still passing at the end")
    text = f"  passes {n}  recoord <= {row['recoord_after_pass_max_s']:.1f} s"
    if row.get("recoord_slow_without_failure_too"):
        free = [p.get("recoord_without_failure_s") for p in row["passes"] if graded(p)]
        text += " (without the failure: " + ("not by the run's end" if None in free else f"{max(free):.1f} s") + ")"
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", metavar="PREFIX", help="scenario prefixes of CASES to run")
    ap.add_argument("--faults", nargs="+", choices=("kill", "silence"), default=["kill", "silence"])
    ap.add_argument("--times", nargs="+", type=number("--times"), metavar="S",
                    help="fault times [s] instead of each scenario's listed ones")
    ap.add_argument("--victims", nargs="+", metavar="ROBOT", help="robots to fail instead of each scenario's listed ones")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scenario override for every run, e.g. run.cut_off=drive")
    ap.add_argument("--after", type=number("--after"), default=AFTER_S, metavar="S",
                    help=f"every run lasts at least this long after its fault [s] (default {AFTER_S:g})")
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
        free: dict[float, Baseline] = {}  # run length -> the run without the failure
        for fault in args.faults:
            for victim in victims:
                for t in times:
                    length = run_length(duration, t, args.after)
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
                              + f"  detours {row['detours']}"
                              + _recoord_text(row), flush=True)
    hit = sum(r["collisions"] > 0 for r in rows)
    short = sum(r["progress_min"] is not None and r["progress_min"] < 0.9 for r in rows)
    slow = sum(_slow_recoord(r) for r in rows)
    unpassed = sum(_unpassed(r) for r in rows)
    own = sum(_slow_recoord(r) and bool(r.get("recoord_slow_without_failure_too")) for r in rows)
    if args.json:
        print(json.dumps({"runs": rows, "runs_with_contact": hit, "runs_below_90_percent_progress": short,
                          "runs_not_recoordinated_within_20s_of_the_pass": slow,
                          "of_which_slow_without_the_failure_too": own,
                          "runs_with_no_pass_to_grade": unpassed,
                          "wall_s": round(time.perf_counter() - t0, 1)}))
    else:
        print(f"{len(rows)} runs, {hit} with contact, {short} with a live robot below 90 % of its progress "
              f"without the failure, {slow} not back in coordination within {RECOORD_GOAL_S:.0f} s of the pass "
              f"({own} of them not back within {RECOORD_GOAL_S:.0f} s of that instant without the failure "
              f"either; {unpassed} more with no pass to grade), "
              f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
