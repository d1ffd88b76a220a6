"""Chaos soak (docs/reference/faults.md, "Chaos soak"): a fleet killed, frozen, stalled, silenced and
partitioned over and over on a seeded schedule, graded from its log.

    copath bench chaos [--scenario e5.4-] [--clock realtime|lockstep]
                       [--policy restart|continue] [--minutes 10] [--faults 40]
                       [--seed 1] [--warmup S] [--kinds kill,stop,stall,silence,partition]
                       [--burst] [--set KEY=VALUE ...] [--inprocess] [--out DIR] [--json]

(or ``python -m orchestrator.studies.bench.chaos`` with the same arguments).

The first fault comes after ``--warmup`` seconds (by default the scenario's ``run.settle_s``, at
least 10 s: a fault in the start-up transient would grade the transient). Faults, drawn from
``--seed`` (the same seed gives the same schedule: times, kinds, victims):

- ``kill``: SIGKILL of a robot's process (in one process: ``run_scenario(kills=...)``, and
  under ``restart`` a new one a second later, ``restarts=...``);
- ``stop``: SIGSTOP for 3-6 s, then SIGCONT (its token lapses after ``run.lease_s``; under
  ``restart`` the orchestrator kills and restarts it before that);
- ``stall``: SIGSTOP for 0.2-0.7 s, shorter than the lease: a delay burst of everything the
  process sends and receives;
- ``silence``: the robot's radio silent for 3-8 s (``network.silence``);
- ``partition``: every link of the robot cut for 3-8 s (``network.partitions``).

``--burst`` adds Gilbert-Elliott loss bursts to every robot-to-robot link for the whole run
(``network.burst_p_gb = 0.02``, ``burst_p_bg = 0.3``). Process faults are sent on the wall
clock, counted from the simulator's "run started" log line (in lockstep the simulated time
runs at its own pace: the schedule's times are then wall seconds); network faults are
windows of simulated time.

Per fault it prints: detection (the simulator's ``robot_lost``, from the fault), time back
(the victim's first command after the fault, or the window's end), restart to first command
(the rejoined process's own ``rejoined_stepping`` event), collisions during the outage, and
re-coordination (from the fault's end until the coordination error among the live robots,
from the truth, is below 0.05 m). Totals: records lost (gaps in the senders' sequence
numbers, the recorder's accounts), collisions, minimum separation against the scenario's
target, and the run's ``ok``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import pathlib
import random
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from copath.scenario import Scenario, load_scenario
from copath.slots import track_coordinate, wrap_near
from copath.wire.keys import Keys
from copath.wire.messages import Command, Event, Truth
from orchestrator.studies.bench.harness import number

KINDS = ("kill", "stop", "stall", "silence", "partition")
PROCESS_KINDS = ("kill", "stop", "stall")
COORD_TOL_M = 0.05
"""Re-coordinated: the live robots' coordination error below this [m] (the issue's goal)."""
MIN_WARMUP_S = 10.0
"""The shortest warm-up before the first fault [s] (chosen: the start record, every robot's
first steps and its first neighbour messages are over by then in every bundled scenario)."""
HOLD_S = 5.0
"""Re-coordinated for good (``recoord_held_s``): the error stays below :data:`COORD_TOL_M` this
long [s] (chosen: a third of the schedule's mean gap between faults; an error that builds up
after the fault's end, as a column slowing behind a restarted robot, is not hidden by a first
instant below the tolerance; docs/journal/faults.md, "First instant or for good")."""


@dataclass
class Fault:
    t: float
    """Run time of the fault [s]."""
    kind: str
    robot: str
    hold_s: float
    """How long it lasts (stop, stall, silence, partition) [s]; 0 for a kill."""
    wall_ns: int | None = None
    """When it was sent (process faults, filled in by the injector)."""
    pid: int | None = None
    note: str = ""


def schedule(names: list[str], duration_s: float, n: int, seed: int, kinds=KINDS,
             warmup_s: float = 10.0, tail_s: float = 15.0) -> list[Fault]:
    """``n`` faults, one per slot of equal length between ``warmup_s`` and the end minus
    ``tail_s``, at a random time within its slot; kind and victim drawn from ``seed``."""
    rng = random.Random(seed)
    span = max(1.0, duration_s - warmup_s - tail_s)
    slot = span / max(1, n)
    out = []
    for i in range(n):
        kind = rng.choice(list(kinds))
        hold = {"kill": 0.0, "stop": rng.uniform(3.0, 6.0), "stall": rng.uniform(0.2, 0.7)}.get(kind)
        if hold is None:
            hold = rng.uniform(3.0, 8.0)
        hold = min(hold, 0.8 * slot) if kind != "kill" else hold
        out.append(Fault(round(warmup_s + slot * (i + rng.uniform(0.05, 0.6)), 3), kind, rng.choice(names),
                         round(hold, 3)))
    return out


def with_faults(scenario: Scenario, faults: list[Fault], burst: bool, **run: Any) -> Scenario:
    """The scenario with ``run`` keys replaced and the silence and partition windows of
    ``faults`` (and loss bursts) added, through its raw tables: every process of a fleet
    loads the same (``copath run`` writes them to the run's scenario.json)."""
    net = dict(scenario.raw.get("network") or {})
    sil = list(net.get("silence", [])) + [{"robot": f.robot, "start_s": f.t, "end_s": f.t + f.hold_s}
                                          for f in faults if f.kind == "silence"]
    edges = scenario.edges()
    par = list(net.get("partitions", [])) + [  # every link of the robot's in the communication graph
        {"links": [list(e) for e in edges if f.robot in e], "start_s": f.t, "end_s": f.t + f.hold_s}
        for f in faults if f.kind == "partition" and any(f.robot in e for e in edges)]
    extra = {"burst_p_gb": 0.02, "burst_p_bg": 0.3, "burst_loss": 1.0} if burst else {}
    network = {**({"silence": sil} if sil else {}), **({"partitions": par} if par else {}), **extra}
    return scenario.with_overrides(run=run, **({"network": network} if network else {}))


# -- injection (separate processes) ----------------------------------------------------

def _cmdline(pid: str) -> list[str]:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return fh.read().decode(errors="replace").split("\0")
    except OSError:
        return []


def _stat(pid: int) -> tuple[str, int]:
    """(state, start time in clock ticks since boot) of ``pid``; ("", 0) once it is gone."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        return fields[0], int(fields[19])  # state (field 3), starttime (field 22)
    except (OSError, IndexError, ValueError):
        return "", 0


def robot_pid(run_id: str, robot: str) -> int | None:
    """The live process of ``robot`` in run ``run_id`` (the newest by start time: pids wrap,
    at 32768 on a default Linux), from /proc."""
    best: tuple[int, int] | None = None
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        argv = _cmdline(d)
        if "agent" not in argv or run_id not in argv:
            continue
        try:
            if argv[argv.index("--robot") + 1] != robot:
                continue
        except (ValueError, IndexError):
            continue
        state, started = _stat(int(d))
        if state in ("Z", "X", ""):
            continue
        best = max(best or (0, 0), (started, int(d)))
    return best[1] if best else None


def _send(pid: int, sig: int) -> bool:
    try:
        os.kill(pid, sig)
        return True
    except (ProcessLookupError, PermissionError):
        return False


class Injector(threading.Thread):
    """Sends the process faults of a schedule on the wall clock, from the run's start."""

    def __init__(self, out: pathlib.Path, run_id: str, faults: list[Fault]) -> None:
        super().__init__(daemon=True)
        self.out, self.run_id = out, run_id
        self.faults = [f for f in faults if f.kind in PROCESS_KINDS]
        self.stop_event = threading.Event()
        self.t0: float | None = None
        self.frozen: list[int] = []

    def _run_started(self) -> bool:
        """The simulator's "run started" line; a simulator that does not log it (before issue
        24): the log's first chunk of records (256 KiB; a few seconds late)."""
        try:
            if "run started" in (self.out / "logs" / "sim.log").read_text(errors="replace"):
                return True
            return (self.out / "run.mcap").stat().st_size > 64 * 1024
        except OSError:
            return False

    def run(self) -> None:
        while not self._run_started():
            if self.stop_event.wait(0.05):
                return
        self.t0 = time.time()
        pending: list[tuple[float, int]] = []  # (wall time, pid) to SIGCONT
        todo = sorted(self.faults, key=lambda f: f.t)
        while (todo or pending) and not self.stop_event.is_set():
            now = time.time()
            for item in [p for p in pending if p[0] <= now]:
                pending.remove(item)
                _send(item[1], signal.SIGCONT)
                self.frozen.remove(item[1]) if item[1] in self.frozen else None
            if todo and now >= self.t0 + todo[0].t:
                f = todo.pop(0)
                pid = robot_pid(self.run_id, f.robot)
                f.pid = pid
                if pid is None:
                    f.note = "no process"
                    continue
                sig = signal.SIGKILL if f.kind == "kill" else signal.SIGSTOP
                f.wall_ns = time.time_ns()
                if not _send(pid, sig):
                    f.note = "gone"
                    continue
                if f.kind != "kill":
                    self.frozen.append(pid)
                    pending.append((time.time() + f.hold_s, pid))
            self.stop_event.wait(0.01)

    def release(self) -> None:
        """Let every process this injector froze go (cleanup)."""
        self.stop_event.set()
        for pid in list(self.frozen):
            _send(pid, signal.SIGCONT)


# -- grading from the log ----------------------------------------------------------------

def _live_coordination(scenario: Scenario, t: np.ndarray, poses: dict[str, np.ndarray],
                       out_masks: dict[str, np.ndarray]) -> np.ndarray | None:
    """(T,) max over the scored pairs of live robots of |xi_i - xi_j| [m] (NaN: no pair)."""
    from orchestrator.analysis.truth import _pairs, team_geometry  # noqa: PLC0415

    geo = team_geometry(scenario)
    if geo is None:
        return None
    names = [n for n in geo.paths if n in poses]
    S = {n: track_coordinate(geo.paths[n], poses[n][:, :2]) for n in names}
    XI = geo.xi(S)
    errs = []
    none = np.zeros(len(t), dtype=bool)
    for a, b in _pairs(scenario, names):
        e = np.abs(wrap_near(XI[a] - XI[b], geo.period))
        errs.append(np.where(out_masks.get(a, none) | out_masks.get(b, none), np.nan, e))
    if not errs:
        return None
    E = np.vstack(errs)
    with np.errstate(all="ignore"):
        return np.where(np.all(np.isnan(E), axis=0), np.nan, np.nanmax(E, axis=0))


def grade(records, scenario: Scenario, run_id: str, faults: list[Fault], metrics: dict[str, Any]) -> dict[str, Any]:
    """Per-fault rows and totals from the run's records (log time [ns], key, record)."""
    keys = Keys(run_id)
    truth = [(ns, r) for ns, _, r in records if isinstance(r, Truth)]
    truth.sort(key=lambda x: x[1].k)
    if not truth:
        return {"faults": [], "totals": {"ok": metrics.get("ok"), "note": "no truth recorded"}}
    t = np.array([r.t for _, r in truth])
    wall = np.array([ns for ns, _ in truth], dtype=float)
    names = list(truth[0][1].names)
    P = np.array([r.poses for _, r in truth])  # (T, R, 3)
    poses = {n: P[:, i, :] for i, n in enumerate(names)}

    def sim_at(ns: float) -> float:
        return float(np.interp(ns, wall, t))

    cmds: dict[str, list[tuple[int, float]]] = {}
    events: list[tuple[int, Event]] = []
    for ns, key, r in records:
        if isinstance(r, Command):
            cmds.setdefault(keys.relative(key).split("/")[1], []).append((ns, float(r.t)))
        elif isinstance(r, Event):
            events.append((ns, r))
    radii = {r.name: r.model.radius for r in scenario.robots}
    iu = np.triu_indices(len(names), 1)
    D = np.linalg.norm(P[:, iu[0], :2] - P[:, iu[1], :2], axis=-1)
    lim = np.array([radii[names[i]] + radii[names[j]] for i, j in zip(*iu)])
    overlap = D < lim
    onsets = np.concatenate([overlap[:1].sum(axis=1), np.logical_and(overlap[1:], ~overlap[:-1]).sum(axis=1)])
    rows, out_masks = [], {n: np.zeros(len(t), dtype=bool) for n in names}
    for f in faults:
        row: dict[str, Any] = {"t": f.t, "kind": f.kind, "robot": f.robot, "hold_s": f.hold_s, "note": f.note,
                               "wall_ns": f.wall_ns}
        if f.kind in PROCESS_KINDS:
            if f.wall_ns is None:
                row.update(detect_s=None, back_s=None, restart_to_cmd_s=None, collisions=None, recoord_s=None)
                rows.append(row)
                continue
            t_f = sim_at(f.wall_ns)
            lost = [ns for ns, e in events if e.source == "sim" and e.what == "robot_lost"
                    and e.detail.get("robot") == f.robot and ns >= f.wall_ns and e.detail.get("cause") != "silence"]
            row["detect_s"] = round((lost[0] - f.wall_ns) / 1e9, 3) if lost and (f.kind == "kill" or lost[0] - f.wall_ns
                                                                                < (f.hold_s + 1.0) * 1e9) else None
            # back: its first command after the loss was seen (a command in flight at the kill is
            # not a return), or after the stall's end
            since = lost[0] if lost and f.kind != "stall" else f.wall_ns + int(f.hold_s * 1e9)
            after = [ns for ns, _ in cmds.get(f.robot, []) if ns > since]
            back_ns = after[0] if after else None
            row["back_s"] = None if back_ns is None else round((back_ns - f.wall_ns) / 1e9, 3)
            stepping = [e for ns, e in events if e.what == "rejoined_stepping" and e.source == f.robot
                        and ns >= f.wall_ns and (back_ns is None or ns <= back_ns + 2e9)]
            row["restart_to_cmd_s"] = stepping[0].detail.get("since_process_start_s") if stepping else None
            t_back = sim_at(back_ns) if back_ns is not None else float(t[-1])
        else:
            t_f, t_back = f.t, f.t + f.hold_s
            kinds = ("robot_lost",) if f.kind == "silence" else ("cut_off", "robot_lost")
            det = [e.t for _, e in events if e.what in kinds and e.t >= t_f - 1e-9
                   and (e.source == f.robot or e.detail.get("robot") == f.robot)]
            row["detect_s"] = round(det[0] - t_f, 3) if det and det[0] <= t_back + 1.0 else None
            row["back_s"] = round(f.hold_s, 3)
            row["restart_to_cmd_s"] = None
        window = (t >= t_f - 1e-9) & (t <= t_back + 1e-9)
        row["collisions"] = int(onsets[window].sum())
        # the victim's nearest robot from the fault to 5 s after its return (a restarted robot
        # starts with an empty safety picture: docs/reference/faults.md)
        near = (t >= t_f - 1e-9) & (t <= t_back + 5.0)
        mine = [j for j, (a, b) in enumerate(zip(*iu)) if f.robot in (names[a], names[b])]
        row["victim_min_sep_m"] = round(float(D[near][:, mine].min()), 3) if near.any() and mine else None
        if f.kind in ("kill", "stop"):
            out_masks[f.robot] |= window
        row["_t_back"] = t_back
        row["_t_f"] = t_f
        rows.append(row)
    coord = _live_coordination(scenario, t, poses, out_masks)
    starts = sorted(r["_t_f"] for r in rows if r.get("_t_f") is not None)
    for row in rows:
        t_back = row.pop("_t_back", None)
        t_f = row.pop("_t_f", None)
        if t_back is None:
            continue
        row["t_sim"] = round(t_f, 2)
        if coord is None:
            row["recoord_s"] = row["coord_before_m"] = None
            continue
        # the team at the fault: the largest live error over the second before it (a fault
        # that hits a team not yet coordinated, in the scenario's own transient or before an
        # earlier fault's error is absorbed, is not what put the error there)
        before = coord[(t >= t_f - 1.0 - 1e-9) & (t < t_f - 1e-9)]
        before = before[np.isfinite(before)]
        row["coord_before_m"] = round(float(before.max()), 4) if len(before) else None
        ok = np.nonzero((t >= t_back - 1e-9) & (coord < COORD_TOL_M))[0]
        row["recoord_s"] = round(float(t[ok[0]] - t_back), 2) if len(ok) else None
        t_next = next((x for x in starts if x > t_f + 1e-9), None)
        row["recoord_held_s"] = held_below(t, coord, t_back, t_next)
        # held only until the next fault began, not for HOLD_S: counted as held, and said
        row["held_cut_by_next_fault"] = bool(
            row["recoord_held_s"] is not None and t_next is not None
            and t_back + row["recoord_held_s"] + HOLD_S > t_next + 1e-9)
    fleet = metrics.get("fleet", {})
    target = (scenario.raw.get("targets") or {}).get("min_separation_m")
    restarts = [r["restart_to_cmd_s"] for r in rows if r.get("restart_to_cmd_s") is not None]
    never = [n for n, m in metrics.get("robots", {}).items() if m.get("outage_open")]
    totals = {
        "faults": len(rows),
        "faults_sent": sum(1 for f in faults if f.kind not in PROCESS_KINDS or f.wall_ns is not None),
        "records_lost": fleet.get("messages_lost"),
        "accounts_reconstructed": fleet.get("accounts_reconstructed"),
        "messages_published": fleet.get("messages_published"),
        "messages_recorded": fleet.get("messages_recorded"),
        "collisions": fleet.get("collisions"),
        "min_separation_m": fleet.get("min_separation_m"),
        "min_separation_target_m": target,
        "victim_min_sep_m": min((r["victim_min_sep_m"] for r in rows if r.get("victim_min_sep_m") is not None),
                                default=None),
        "restart_to_cmd_max_s": max(restarts) if restarts else None,
        "restarts_over_2s": sum(1 for x in restarts if x > 2.0),
        "not_back": sum(1 for r in rows if r["kind"] in ("kill", "stop") and r.get("back_s") is None),
        "recoord_max_s": max((r["recoord_s"] for r in rows if r.get("recoord_s") is not None), default=None),
        "recoord_over_20s_or_never": sum(1 for r in rows if r.get("t_sim") is not None
                                         and (r.get("recoord_s") is None or r["recoord_s"] > 20.0)),
        "faults_on_a_settled_team": sum(1 for r in rows if _settled(r)),
        "recoord_over_20s_or_never_settled": sum(1 for r in rows if _settled(r)
                                                 and (r.get("recoord_s") is None or r["recoord_s"] > 20.0)),
        "recoord_held_over_20s_or_never": sum(1 for r in rows if r.get("t_sim") is not None
                                              and (r.get("recoord_held_s") is None or r["recoord_held_s"] > 20.0)),
        "recoord_held_over_20s_or_never_settled": sum(1 for r in rows if _settled(r) and (
            r.get("recoord_held_s") is None or r["recoord_held_s"] > 20.0)),
        "held_cut_by_next_fault": sum(1 for r in rows if r.get("held_cut_by_next_fault")),
        "outage_open": never,
        "deadline_miss_rate": fleet.get("deadline_miss_rate"),
        "ok": metrics.get("ok"),
        "failure": metrics.get("failure"),
    }
    return {"faults": rows, "totals": totals}


def held_below(t: np.ndarray, coord: np.ndarray, t_back: float, t_next: float | None = None,
               later: bool = True) -> float | None:
    """Seconds from ``t_back`` to the first instant from which the coordination error stays
    below :data:`COORD_TOL_M` for :data:`HOLD_S`, or until the next fault begins (``t_next``)
    or the run ends, whichever comes first; None if never. An error that builds up after the
    next fault has begun is that fault's, graded in its own row (docs/journal/faults.md, "A
    window ends at the next fault"). NaN (no live pair) counts as below.

    ``later``: a stretch that begins after the next fault has begun still counts (the chaos
    soak: the next fault only ever ends a stretch early); False, it is the next fault's and this
    one is None (the failure sweep's passes, docs/reference/faults.md: a pass whose team is not
    back when the next pass begins is not back within its window)."""
    below = ~(coord >= COORD_TOL_M)  # NaN: no pair to grade
    k = int(np.searchsorted(t, t_back - 1e-9))
    nxt = len(t) if t_next is None else int(np.searchsorted(t, t_next - 1e-9))  # first instant of the next fault
    bad = np.nonzero(~below[k:])[0] + k  # the instants at or over the tolerance from t_back on
    start = k  # each stretch below begins at t_back or just after an instant over
    for b in (*bad.tolist(), len(t)):
        if not later and k < nxt < start:
            return None
        if b > start and (b == len(t) or t[b] - t[start] >= HOLD_S - 1e-9 or start < nxt <= b):
            return round(float(t[start] - t_back), 2)
        start = b + 1
    return None


def _settled(row: dict) -> bool:
    """The fault hit a coordinated team: its live robots' error below :data:`COORD_TOL_M` over
    the second before it (docs/reference/faults.md, "Chaos soak")."""
    c = row.get("coord_before_m")
    return row.get("t_sim") is not None and c is not None and c < COORD_TOL_M


# -- the soak ----------------------------------------------------------------------------

@dataclass
class Soak:
    scenario: Scenario
    faults: list[Fault]
    result: dict[str, Any] = field(default_factory=dict)
    out: pathlib.Path | None = None


def warmup_for(scen: Scenario) -> float:
    """The default warm-up before the first fault [s]: the scenario's own ``run.settle_s`` (the
    end of its transient, from which its errors are graded), at least :data:`MIN_WARMUP_S`. A
    fault that hits a team still in its start-up transient grades that transient, not its own
    return (docs/reference/faults.md, "Chaos soak")."""
    return max(MIN_WARMUP_S, float(scen.run.settle_s or 0.0))


def prepare(scenario: Scenario | str, clock: str, policy: str, minutes: float, n_faults: int, seed: int,
            kinds=KINDS, burst: bool = False, overrides: list[str] | None = None,
            warmup_s: float | None = None) -> tuple[Scenario, list[Fault]]:
    """The scenario with the soak's run settings and its faults; ``warmup_s`` None:
    :func:`warmup_for` the scenario."""
    scen = load_scenario(_config(scenario)) if isinstance(scenario, str) else scenario
    if overrides:  # ``--set key=value``: the scenario's own keys, validated as ``copath run --set``
        from orchestrator import api  # noqa: PLC0415

        scen = api.load(scen, overrides)
    duration = 60.0 * minutes
    warmup = warmup_for(scen) if warmup_s is None else float(warmup_s)
    if not 0.0 <= warmup < duration:
        key = "warmup_s" if warmup_s is not None else "the warm-up (the scenario's run.settle_s)"
        raise ValueError(f"{key} = {warmup:g} is not allowed; must be >= 0 and below the soak's {duration:g} s")
    faults = schedule(list(scen.robot_names), duration, n_faults, seed, kinds, warmup_s=warmup)
    return with_faults(scen, faults, burst, clock=clock, on_robot_failure=policy, duration_s=duration), faults


def _config(name: str) -> pathlib.Path:
    p = pathlib.Path(name)
    if p.is_file():
        return p
    from orchestrator.testkit.scenarios import config  # noqa: PLC0415

    return config(name)


def soak_fleet(scenario: Scenario, faults: list[Fault], out: pathlib.Path, run_id: str | None = None) -> dict:
    """Run the soak as separate processes over Zenoh (``copath run``), faults injected by pid."""
    from orchestrator.run.fleet import RunOptions, run_fleet  # noqa: PLC0415

    out = pathlib.Path(out)
    run_id = run_id or f"chaos-{os.getpid()}-{int(time.time())}"
    fields = {f.name for f in dataclasses.fields(RunOptions)}
    extra = {"max_restarts": 10_000} if "max_restarts" in fields else {}
    opts = RunOptions(out_dir=out, run_id=run_id, progress=False,
                      wall_timeout_s=120.0 + 3.0 * scenario.run.duration_s * (1 if scenario.run.clock == "realtime" else 10),
                      **extra)
    inj = Injector(out, run_id, faults)
    inj.start()
    try:
        outcome = run_fleet(scenario, opts)
    finally:
        inj.release()
        inj.join(timeout=5)
    metrics = dict(outcome.metrics or {})
    metrics.setdefault("ok", outcome.ok)
    metrics.setdefault("failure", None if outcome.ok else outcome.reason)
    return grade(outcome.records, scenario, run_id, faults, metrics)


def soak_inprocess(scenario: Scenario, faults: list[Fault], restart_after_s: float = 1.0) -> dict:
    """The same soak in one process (lockstep): a kill is ``run_scenario(kills=...)`` and,
    under ``restart``, a new process ``restart_after_s`` later; stop and stall have no
    in-process form and are left out (noted)."""
    from orchestrator.run.inprocess import run_scenario  # noqa: PLC0415

    kills: list[tuple[str, float]] = []
    restarts: list[tuple[str, float]] = []
    busy: dict[str, float] = {}
    for f in faults:
        if f.kind in ("stop", "stall"):
            f.note = "no in-process form"
            continue
        if f.kind != "kill":
            continue
        if busy.get(f.robot, -1.0) >= f.t:
            f.note = "robot still down"
            continue
        kills.append((f.robot, f.t))
        # the link closes after tick round(t / dt): the robot misses the next one (log time = sim time)
        f.wall_ns = int(round((round(f.t / scenario.run.dt) + 1) * scenario.run.dt * 1e9)) - 1
        if scenario.run.on_robot_failure == "restart":
            restarts.append((f.robot, f.t + restart_after_s))
            busy[f.robot] = f.t + restart_after_s
        else:
            busy[f.robot] = float("inf")
    res = _run_inprocess(run_scenario, scenario, kills, restarts)
    metrics = dict(res.metrics)
    metrics.setdefault("ok", res.ok)
    return grade(res.records, scenario, res.metrics["run_id"], [f for f in faults if f.kind not in ("stop", "stall")],
                 metrics)


def _run_inprocess(run_scenario, scenario, kills, restarts):
    k: dict[str, list[float]] = {}
    r: dict[str, list[float]] = {}
    for n, t in kills:
        k.setdefault(n, []).append(t)
    for n, t in restarts:
        r.setdefault(n, []).append(t)
    return run_scenario(scenario, kills=k, restarts=r)


def regrade(out: pathlib.Path, result: dict) -> dict:
    """Grade a soak's run directory again from its log and its printed result (``--json``);
    a row without ``wall_ns`` (an older result) takes it from its ``t_sim`` on the truth."""
    from orchestrator.log.mcap import read_log  # noqa: PLC0415
    from orchestrator.analysis.metrics import metrics_from_log  # noqa: PLC0415

    out = pathlib.Path(out)
    log = read_log(out / "run.mcap")
    scen = load_scenario(out / "scenario.json")
    truth = sorted(((ns, r) for ns, _, r in log.records if isinstance(r, Truth)), key=lambda x: x[1].k)
    tt = np.array([r.t for _, r in truth])
    ww = np.array([ns for ns, _ in truth], dtype=float)
    faults = []
    for r in result["faults"]:
        ns = r.get("wall_ns")
        if ns is None and r["kind"] in PROCESS_KINDS and r.get("t_sim") is not None:
            ns = int(np.interp(r["t_sim"], tt, ww))
        faults.append(Fault(r["t"], r["kind"], r["robot"], r["hold_s"], ns, note=r.get("note", "")))
    return grade(log.records, scen, log.run_id, faults, metrics_from_log(out / "run.mcap"))


def print_table(title: str, result: dict, file=sys.stdout) -> None:
    print(f"\n{title}", file=file)
    print(f"{'t':>7} {'t_sim':>7} {'kind':<9} {'robot':<7} {'hold':>5} {'detect':>7} {'back':>7} {'restart>cmd':>11} "
          f"{'coll':>4} {'recoord':>7} {'held':>6} {'before':>6} {'vsep':>6}  note", file=file)

    def fmt(v, w, p=2):
        return f"{'-':>{w}}" if v is None else f"{v:>{w}.{p}f}" if isinstance(v, float) else f"{v:>{w}}"

    for r in result["faults"]:
        print(f"{r['t']:>7.1f} {fmt(r.get('t_sim'), 7, 1)} {r['kind']:<9} {r['robot']:<7} {r['hold_s']:>5.1f} "
              f"{fmt(r.get('detect_s'), 7)} {fmt(r.get('back_s'), 7)} {fmt(r.get('restart_to_cmd_s'), 11)} "
              f"{fmt(r.get('collisions'), 4)} {fmt(r.get('recoord_s'), 7, 1)} {fmt(r.get('recoord_held_s'), 6, 1)} {fmt(r.get('coord_before_m'), 6, 3)} "
              f"{fmt(r.get('victim_min_sep_m'), 6, 3)}"
              f"  {r.get('note', '')}", file=file)
    print("totals: " + ", ".join(f"{k}={v}" for k, v in result["totals"].items()), file=file)


def _kinds(text: str) -> tuple[str, ...]:
    """``--kinds``: a comma-separated subset of :data:`KINDS`."""
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise argparse.ArgumentTypeError(f"--kinds = {bad[0] if bad else text!r} is not allowed; "
                                         f"allowed: a comma-separated subset of {','.join(KINDS)}")
    return kinds


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``copath bench chaos`` (and ``python -m orchestrator.studies.bench.chaos``)."""
    p.add_argument("--scenario", default="e5.4-", help="scenario file or config prefix [e5.4-]")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime")
    p.add_argument("--policy", choices=("restart", "continue"), default="restart")
    p.add_argument("--minutes", type=number("--minutes"), default=10.0)
    p.add_argument("--faults", type=number("--faults", int), default=40)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--warmup", type=number("--warmup", strict=False), default=None, metavar="S",
                   help="seconds before the first fault [the scenario's run.settle_s, at least 10]")
    p.add_argument("--kinds", type=_kinds, default=KINDS, help=f"comma-separated subset of {','.join(KINDS)}")
    p.add_argument("--burst", action="store_true", help="Gilbert-Elliott loss bursts on every link, all run")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario key, as `copath run --set` (repeatable), e.g. run.cut_off=drive")
    p.add_argument("--inprocess", action="store_true", help="one process, lockstep, simulated kills")
    p.add_argument("--out", default=None, help="run directory [a new temporary one]")
    p.add_argument("--json", action="store_true")
    p.add_argument("--regrade", default=None, metavar="RESULT.json",
                   help="grade the run in --out again from its log and this printed --json result")


def run(a: argparse.Namespace) -> int:
    """Run the soak the parsed arguments ``a`` describe; print its table (or JSON)."""
    if a.regrade:
        res = regrade(pathlib.Path(a.out), json.loads(pathlib.Path(a.regrade).read_text()))
        print(json.dumps(res, indent=1, default=str)) if a.json else print_table(f"regraded: {a.out}", res)
        return 0
    kinds = a.kinds
    clock = "lockstep" if a.inprocess else a.clock
    try:
        scen, faults = prepare(a.scenario, clock, a.policy, a.minutes, a.faults, a.seed, kinds, a.burst, a.set,
                               warmup_s=a.warmup)
    except ValueError as e:
        print(f"copath bench chaos: {e}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    if a.inprocess:
        res = soak_inprocess(scen, faults)
    else:
        import tempfile  # noqa: PLC0415

        out = pathlib.Path(a.out) if a.out else pathlib.Path(tempfile.mkdtemp(prefix="copath-chaos-"))
        res = soak_fleet(scen, faults, out)
        res["out"] = str(out)
    res["wall_s"] = round(time.monotonic() - t0, 1)
    res["load"] = os.getloadavg()
    if a.json:
        print(json.dumps(res, indent=1, default=str))
    else:
        print_table(f"chaos soak: {scen.id}, {clock}, {a.policy}, {a.minutes:g} min, {len(faults)} faults, "
                    f"seed {a.seed}{', bursts' if a.burst else ''}{', in one process' if a.inprocess else ''}"
                    f"{''.join(', ' + s for s in a.set)}"
                    f" (wall {res['wall_s']} s, load {res['load'][0]:.1f})", res)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m orchestrator.studies.bench.chaos", description=__doc__.split("\n\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
