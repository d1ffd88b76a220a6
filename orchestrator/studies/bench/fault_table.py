"""The fault table (docs/journal/faults.md, "The fault table on E5.5"): every fault or attack of ``tests/faults``
tried once on a short E5.5 run (Sec. 5.5, lockstep over Zenoh), with what happened.

    python -m orchestrator.studies.bench.fault_table [--only NAME ...] [--json]

Per row: whether the run met the scenario's ``[targets]`` (``copath.grading``, graded
from the simulator's truth in the log; the targets missed are named), messages lost
(lockstep: each process's closing account of what it published against what the
recorder holds on its keys, less what an attacker injected there; 0 expected), the
detection time (wall seconds from the fault to the record that shows it: the
simulator's ``robot_lost`` event or ``End``, a receiver's first ``messages_rejected``
event, or the orchestrator's exit), the rejects counted (``fleet.messages_rejected``) and
the run's reason. Rows that need root and network namespaces are left out, with the
reason, where that is not permitted.

The faults are injected with the test kit the test suite uses too (``orchestrator.testkit``)."""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import pathlib
import re
import signal
import sys
import tempfile
import time
from typing import Any, Callable

import msgpack

from copath.grading import grade
from copath.scenario import load_scenario
from copath.wire.keys import Keys
from copath.wire.messages import Command, End, PeerEnvelope
from copath.wire.session import free_port, loopback_endpoint
from orchestrator.log.mcap import read_log
from orchestrator.testkit import hosts as netns
from orchestrator.testkit.attacker import attacker, session, wait_for_truth
from orchestrator.testkit.fuzz import fuzz_payloads
from orchestrator.testkit.hosts import DROP, kill_remote_router, run_across_hosts
from orchestrator.testkit.processes import Procs, child_pids, cmdline, unfreeze, victim
from orchestrator.testkit.scenarios import config

SCENARIO = config("e5.5-")
DURATION = "60"


# -- running and reading a case -----------------------------------------------------------

class Case:
    """One run: its directory, run id, the fault's wall time and what an attacker injected."""

    def __init__(self, out: pathlib.Path, run_id: str) -> None:
        self.out, self.run_id, self.keys = out, run_id, Keys(run_id)
        self.t_fault: int | None = None
        self.t_exit: int | None = None
        self.injected: dict[str, int] = {}
        """Records an attacker published that the recorder also heard (open bus), per key."""
        self.detect: str = "none"
        """What marks detection: lost (robot_lost/End), reject (messages_rejected), exit, none."""
        self.note: str = ""
        self.fixed_detection: float | None = None
        self.sim_fault_t: float | None = None
        """A fault set in simulated time (silence): detection is then in simulated seconds."""
        """A detection time the fault's helper measured itself."""

    def inject(self, link, key: str, data: bytes, recorded: bool = True) -> None:
        link.publish_bytes(key, data)
        if recorded:
            self.injected[key] = self.injected.get(key, 0) + 1

    def start(self, procs: Procs, *extra: str, duration: str = DURATION) -> tuple[Any, str]:
        ep = loopback_endpoint(free_port())
        p = procs.start(["-m", "orchestrator", "run", str(SCENARIO), "--out", str(self.out), "--run-id", self.run_id,
                         "--duration", duration, "--listen", ep, "-q", "--no-plots", *extra])
        return p, ep

    def wait(self, p, timeout: float = 400) -> int:
        rc = p.wait(timeout=timeout)
        self.t_exit = time.time_ns()
        return rc


def _under_way(case: Case, p, size: int = 200_000, timeout: float = 150) -> None:
    mcap = case.out / "run.mcap"
    deadline = time.monotonic() + timeout
    while not (mcap.is_file() and mcap.stat().st_size > size):
        if p.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the run did not get under way: {p.stderr.read().decode()[-1500:]}")
        time.sleep(0.05)


def _publisher(rel: str) -> str | None:
    """The run process that publishes on a key (relative to the run prefix), None for none."""
    parts = rel.split("/")
    if parts[0] == "robot" and len(parts) >= 3:
        return "sim" if parts[2] == "obs" else parts[1]
    if parts[0] == "peer" and len(parts) >= 2:
        return parts[1]
    if parts[0] == "sim":
        return "sim"
    if len(parts) == 2 and parts[1] == "event":
        return parts[0]
    return None


def messages_lost(log, keys: Keys, injected: dict[str, int]) -> int | None:
    """Messages a process published (its closing account) that the recorder does not hold,
    summed over the processes that left an account and were not restarted; None when none did."""
    published = {r.proc: r.published for _, _, r in log.records if getattr(r, "TYPE", "") == "stats"}
    if not published:
        return None
    recorded: dict[str, int] = {}
    for key, n in log.counts.items():
        proc = _publisher(keys.relative(key))
        if proc is not None:
            recorded[proc] = recorded.get(proc, 0) + n - injected.get(key, 0)
    restarted = {r.detail["robot"] for _, _, r in log.records
                 if getattr(r, "TYPE", "") == "event" and r.what == "robot_rejoined"}
    return sum(max(0, pub - recorded.get(proc, 0)) for proc, pub in published.items() if proc not in restarted)


def summarise(name: str, case: Case) -> dict[str, Any]:
    m = json.loads((case.out / "metrics.json").read_text())
    log = read_log(case.out / "run.mcap")
    results = grade(load_scenario(SCENARIO).targets, m)
    missed = [f"{r.target.key}" + (f" ({r.worst})" if r.worst else "") for r in results if not r.passed]
    detection = None
    if case.sim_fault_t is not None:  # first loss record after the fault, in simulated time
        marks_t = [r.t for _, _, r in log.records if getattr(r, "TYPE", "") == "end" and not r.ok
                   or getattr(r, "TYPE", "") == "event" and r.what == "robot_lost"]
        marks_t = [t for t in marks_t if t >= case.sim_fault_t]
        if marks_t:
            detection, case.detect = min(marks_t) - case.sim_fault_t, "lost, simulated s"
    elif case.t_fault is not None:
        marks: list[int] = []
        for t, _, r in log.records:
            kind = getattr(r, "TYPE", "")
            if case.detect == "lost" and (kind == "end" or kind == "event" and r.what == "robot_lost"):
                marks.append(t)
            elif case.detect == "reject" and kind == "event" and r.what == "messages_rejected":
                marks.append(t)
        marks = [t for t in marks if t >= case.t_fault]
        if marks:
            detection = (min(marks) - case.t_fault) / 1e9
        elif case.detect == "exit" and case.t_exit is not None:
            detection = (case.t_exit - case.t_fault) / 1e9
    return {"fault": name, "ok": m["ok"], "met_targets": not missed, "targets_missed": missed,
            "messages_lost": messages_lost(log, case.keys, case.injected), "detection_s": detection,
            "detected_by": case.detect if detection is not None else None,
            "rejects": m["fleet"].get("messages_rejected"), "reason": m["failure"] or "completed",
            "note": case.note}


# -- the faults ---------------------------------------------------------------------------

def _robot(policy: str, sig: signal.Signals, duration: str = DURATION) -> Callable[[Case, Procs], None]:
    def run(case: Case, procs: Procs) -> None:
        p, _ = case.start(procs, "--on-robot-failure", policy, duration=duration)
        pid = victim(p, case.out)
        case.t_fault, case.detect = time.time_ns(), "lost"
        os.kill(pid, sig)
        try:
            case.wait(p)
        finally:
            unfreeze(pid, sig)
    return run


def sim_killed(case: Case, procs: Procs) -> None:
    p, _ = case.start(procs)
    _under_way(case, p)

    pid = next(q for q in child_pids(p.pid) if "sim" in cmdline(q))
    t_kill = time.time()
    case.t_fault, case.detect = time.time_ns(), "agents"
    os.kill(pid, signal.SIGKILL)
    case.wait(p)
    # the agents notice the simulator's token going (their log lines), the orchestrator its exit
    seen = []
    for log in (case.out / "logs").glob("r*.log"):
        for line in log.read_text(errors="replace").splitlines():
            if "simulator" in line and line[:4].isdigit():
                t = datetime.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
                if t >= t_kill - 0.01:
                    seen.append(t)
                    break
    case.fixed_detection = (min(seen) - t_kill) if seen else None
    case.note = (f"the orchestrator exited {(case.t_exit - case.t_fault) / 1e9:.1f} s after the kill "
                 "(children stopped, log finished, metrics computed)")


def _nan_peer_records() -> list[bytes]:
    good = PeerEnvelope("r2", 1, 0.5, "coord_state", [0.0, 0.0], {"s": 0.0, "sdot": 0.2, "s_d": 0.0}).to_dict()
    return [msgpack.packb(dict(good, payload={"s": math.nan, "sdot": 0.2, "s_d": 0.0})),
            msgpack.packb(dict(good, stamp=math.nan)),
            msgpack.packb(dict(good, payload={"s": 0.0, "sdot": math.inf, "s_d": 0.0}))]


def _open_attack(inject: Callable[[Case, Any], None], ticks: int = 30) -> Callable[[Case, Procs], None]:
    def run(case: Case, procs: Procs) -> None:
        p, ep = case.start(procs, "--no-secure")
        with attacker(ep) as bad:
            wait_for_truth(bad, case.keys, ticks, p)
            case.t_fault, case.detect = time.time_ns(), "reject"
            inject(case, bad)
            time.sleep(0.5)
        case.wait(p)
    return run


def forged_end(case: Case, bad) -> None:
    case.inject(bad, case.keys.end, End(5, 0.5, "forged end", True).pack())


def nan_peers(case: Case, bad) -> None:
    for _ in range(20):
        for data in _nan_peer_records():
            case.inject(bad, case.keys.peer_broadcast("r2"), data)


def fuzz_open(case: Case, bad) -> None:
    import random  # noqa: PLC0415

    keys = case.keys
    targets = [keys.obs("r1"), keys.peer_broadcast("r2"), keys.peer_direct("r2", "r1"), keys.start, keys.end]
    for i, data in enumerate(fuzz_payloads(random.Random(10), 3000, "r1", "r2")):
        case.inject(bad, targets[i % len(targets)], data)
        if i % 200 == 0:
            time.sleep(0.01)


def forged_cmds_open(case: Case, procs: Procs) -> None:
    """A stranger answers r1's observations with its own commands for 10 simulated seconds."""
    p, ep = case.start(procs, "--no-secure")
    keys = case.keys
    with attacker(ep) as bad:
        wait_for_truth(bad, keys, 30, p)
        case.t_fault, case.detect = time.time_ns(), "none"  # well-formed: nothing on an open bus can tell
        sent = []

        def answer(key: str, data: bytes) -> None:
            if len(sent) < 100:
                k = msgpack.unpackb(data)["k"]
                case.inject(bad, keys.cmd("r1"), Command(k, 0.1 * k, [0.3, -0.3], 0.0, {}).pack())
                sent.append(k)

        bad.subscribe_raw(keys.obs("r1"), answer)
        deadline = time.monotonic() + 120
        while len(sent) < 100 and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
    case.wait(p)
    case.note = f"{len(sent)} forged commands, each answering r1's observation"


def _secure_attack(kind: str) -> Callable[[Case, Procs], None]:
    def run(case: Case, procs: Procs) -> None:
        import random  # noqa: PLC0415

        p, ep = case.start(procs, "--secure")
        keys = case.keys
        cred = case.out / "secrets" / "r2.json5"
        deadline = time.monotonic() + 150
        while not cred.is_file():
            if p.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("no credentials were written")
            time.sleep(0.05)
        with session(ep, str(cred), timeout_ms=60000) as bad:
            _under_way(case, p)
            case.t_fault, case.detect = time.time_ns(), "none"  # refused by the router: nothing to detect
            if kind == "cmds":
                for i in range(100):
                    case.inject(bad, keys.cmd("r1"), Command(i, 0.1 * i, [0.3, -0.3], 0.0, {}).pack(), recorded=False)
                    case.inject(bad, keys.end, End(i, 0.1 * i, "forged end", True).pack(), recorded=False)
                    time.sleep(0.01)
            else:
                targets = [keys.obs("r1"), keys.peer_broadcast("r1"), keys.peer_direct("r3", "r1"), keys.start,
                           keys.end, keys.cmd("r1"), keys.truth]
                for i, data in enumerate(fuzz_payloads(random.Random(11), 3000, "r1", "r3")):
                    case.inject(bad, targets[i % len(targets)], data, recorded=False)
                    if i % 200 == 0:
                        time.sleep(0.01)
            time.sleep(0.5)
        case.wait(p)
        case.note = "with r2's credentials; refused by the router's access control"
    return run


def _network(*settings: str, note: str = "", sim_fault_t: float | None = None) -> Callable[[Case, Procs], None]:
    def run(case: Case, procs: Procs) -> None:
        case.sim_fault_t = sim_fault_t
        p, _ = case.start(procs, *settings)
        case.wait(p)
        case.note = note
    return run


def netns_drop(case: Case, procs: Procs) -> None:
    with netns.two_hosts() as hosts:
        hosts.drop(hosts.a, DROP)
        try:
            run_across_hosts(case.out, procs, hosts, case.run_id, duration_s=float(DURATION))
        finally:
            netns.stop_all(procs)
        case.note = f"{hosts.dropped(hosts.a)} packets dropped on the link; r2 on host B"


def router_killed(policy: str) -> Callable[[Case, Procs], None]:
    def run(case: Case, procs: Procs) -> None:
        with netns.two_hosts() as hosts:
            try:
                res = kill_remote_router(case.out, procs, hosts, policy, case.run_id, float(DURATION))
            finally:
                netns.stop_all(procs)
        case.note = f"r2, r3 behind host B's router; detection {res['detection_s']:.2f} s (kill to the loss record)"
        case.fixed_detection, case.detect = res["detection_s"], "lost"
    return run


SILENCE = 'network.silence=[{robot="r2",start_s=10.0,end_s=20.0}]'

CASES: dict[str, tuple[str, Callable[[Case, Procs], None], bool]] = {
    # name: (label, run, needs netns)
    "kill-fail": ("r3 killed (SIGKILL), on_robot_failure fail", _robot("fail", signal.SIGKILL), False),
    "kill-continue": ("r3 killed (SIGKILL), continue", _robot("continue", signal.SIGKILL), False),
    # 200 s: the restarted process needs its start-up before the run ends (a restart that
    # comes up after the end never hears it: docs/reference/faults.md)
    "kill-restart": ("r3 killed (SIGKILL), restart (200 s run)", _robot("restart", signal.SIGKILL, "200"), False),
    "stop-continue": ("r3 frozen (SIGSTOP), continue", _robot("continue", signal.SIGSTOP), False),
    "sim-killed": ("the simulator killed (SIGKILL)", sim_killed, False),
    "forged-end": ("a forged sim/end (open bus)", _open_attack(forged_end), False),
    "forged-cmds-open": ("forged commands for r1 (open bus)", forged_cmds_open, False),
    "forged-cmds-secure": ("forged commands for r1 and sim/end (secure mode)", _secure_attack("cmds"), False),
    "fuzz-open": ("3000 fuzzed records (open bus)", _open_attack(fuzz_open), False),
    "fuzz-secure": ("3000 fuzzed records (secure mode)", _secure_attack("fuzz"), False),
    "nan-peers": ("NaN/inf peer payloads and stamps (open bus)", _open_attack(nan_peers), False),
    "silence-fail": ("radio silence of r2, 10-20 s, fail", _network("--set", SILENCE, sim_fault_t=10.0), False),
    "silence-continue": ("radio silence of r2, 10-20 s, continue",
                         _network("--set", SILENCE, "--on-robot-failure", "continue", sim_fault_t=10.0), False),
    "partition": ("partition r1-r2, 10 s", _network('--set', 'network.partitions=[{links=[["r1","r2"]],start_s=10.0,'
                                                    'end_s=20.0}]', note="r1-r2 cut 10-20 s"), False),
    "delay-loss": ("delay 100 ms + loss 0.1", _network("--delay", "100", "--loss", "0.1",
                                                       note="injected by the fault layer"), False),
    "netns-drop": (f"two hosts (netns), iptables drops {DROP:.0%} of one link's packets", netns_drop, True),
    "router-fail": ("host B's router killed (r2, r3 behind it), fail", router_killed("fail"), True),
    "router-continue": ("host B's router killed (r2, r3 behind it), continue", router_killed("continue"), True),
}


def run_case(name: str, tmp: pathlib.Path) -> dict[str, Any]:
    label, fn, needs_netns = CASES[name]
    if needs_netns:
        why = netns.why_not(iptables=name == "netns-drop")
        if why:
            return {"fault": label, "skipped": why}
    case = Case(tmp / name, name.replace("-", "_"))
    procs = Procs()
    try:
        fn(case, procs)
    except Exception as exc:  # a case that could not be run is a row that says so
        return {"fault": label, "skipped": f"{type(exc).__name__}: {exc}"[:300]}
    finally:
        netns.stop_all(procs)
    row = summarise(label, case)
    if case.fixed_detection is not None:
        row["detection_s"], row["detected_by"] = case.fixed_detection, case.detect
    return row


def _cell(row: dict[str, Any], key: str) -> str:
    v = row.get(key)
    if key == "met_targets":
        return "yes" if v else "no: " + ", ".join(row["targets_missed"])
    if key == "detection_s":
        return "n/a" if v is None else f"{v:.2f} s ({row['detected_by']})"
    if v is None:
        return "n/a"
    if key == "reason":  # the run directory is a temporary one
        v = re.sub(r"; see \S+", "", str(v))
    return str(v).replace("|", "/").replace("\n", " ")


def markdown(rows: list[dict[str, Any]]) -> str:
    cols = [("fault", "fault or attack"), ("met_targets", "met its targets"), ("messages_lost", "messages lost"),
            ("detection_s", "detection"), ("rejects", "rejects"), ("reason", "reason given"), ("note", "note")]
    out = ["| " + " | ".join(h for _, h in cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        if "skipped" in r:
            why = str(r["skipped"]).replace("|", "/").replace("\n", " ")
            out.append(f"| {r['fault']} | not run: {why} |" + " |" * (len(cols) - 2))
        else:
            out.append("| " + " | ".join(_cell(r, k) for k, _ in cols) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="+", choices=list(CASES), metavar="NAME",
                    help=f"run only these rows ({', '.join(CASES)})")
    ap.add_argument("--json", action="store_true", help="print JSON instead of the markdown table")
    ap.add_argument("--keep", metavar="DIR", help="keep the runs in this directory")
    args = ap.parse_args(argv)
    names = args.only or list(CASES)
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="copath-faults-") as tmpd:
        tmp = pathlib.Path(args.keep) if args.keep else pathlib.Path(tmpd)
        rows = []
        for n in names:
            rows.append(run_case(n, tmp))
            print(f"fault_table: {n} done", file=sys.stderr, flush=True)
    machine = {"cores": os.cpu_count(), "load_1min_start": round(load0, 2),
               "load_1min_end": round(os.getloadavg()[0], 2)}
    if args.json:
        print(json.dumps({"scenario": SCENARIO.stem, "duration_s": float(DURATION), "machine": machine,
                          "rows": rows}, indent=1))
    else:
        print(markdown(rows))
        print(f"\n{SCENARIO.stem}, lockstep, {DURATION} s; {machine['cores']} cores, "
              f"load {machine['load_1min_start']} at start, {machine['load_1min_end']} at end")
    return 0 if all("skipped" not in r for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
