"""``copath bench latency``: neighbour-message latency in a realtime fleet, and recorder throughput.

1. Neighbour messages: a realtime consensus fleet (``copath bench scale``'s scenario) of
   ``--robots`` robots at ``--rate`` Hz. Each agent measures the age of every neighbour
   message on arrival: wall clock minus the message's stamp (the sender's control
   instant, on the clock every process synchronised at ``sim/start``), so the age is the
   sender's step plus the path through the router. Printed: p50 over all agents, and the
   worst agent's p99 and maximum, with the controllers' step time p99 for comparison.
2. Recorder: a separate publisher process (``ZenohLink`` client, congestion control
   BLOCK) puts ``--messages`` peer envelopes as fast as it can through the run's router
   into the recorder (``orchestrator/log/writer.py``), once writing only the log and once
   also building the Foxglove views of the E5.4 scenario, as ``copath run`` does.
   Printed: the publisher's rate, the recorder's rate (first to last message received)
   and the messages lost.
"""

from __future__ import annotations

import argparse
import pathlib
import subprocess
import sys
import time
from typing import Any

from orchestrator.studies.bench.harness import emit, print_table, scratch_dir

__all__ = ["add_arguments", "run"]

_PUBLISHER = r"""
import sys, time
from copath.wire.keys import Keys
from copath.wire.messages import PeerEnvelope
from copath.wire.session import SessionConfig, ZenohLink
endpoint, run_id, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
keys = Keys(run_id)
with ZenohLink.open(SessionConfig(mode="client", connect=(endpoint,))) as link:
    env = PeerEnvelope("r1", 0, 0.0, "consensus", [0.0, 0.0], {"xi": 1.0, "xi_dot": 0.2, "s": 1.0}, None)
    data = env.pack()
    key = keys.peer_broadcast("r1")
    link.publish_bytes(key + "/warmup", data)
    time.sleep(0.5)  # the router has the subscription
    t0 = time.perf_counter()
    for _ in range(n):
        link.publish_bytes(key, data)
    print(n / (time.perf_counter() - t0), flush=True)
    sys.stdin.readline()  # keep the session (and its queued messages) until the recorder has them
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, default=16, help="fleet size for the neighbour latency [16]")
    parser.add_argument("--rate", type=float, default=20.0, help="control rate [Hz] [20]")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S", help="simulated seconds [20]")
    parser.add_argument("--messages", type=int, default=100_000, help="messages through the recorder [100000]")
    parser.add_argument("--no-fleet", action="store_true", help="recorder throughput only")
    parser.add_argument("--no-recorder", action="store_true", help="neighbour latency only")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the tables")


def _fleet(args: argparse.Namespace, root: pathlib.Path) -> dict[str, Any]:
    from copath.scenario import parse_scenario  # noqa: PLC0415
    from copath.wire.keys import Keys  # noqa: PLC0415

    from orchestrator.studies.bench.scale import scenario_table  # noqa: PLC0415
    from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet  # noqa: PLC0415
    from orchestrator.analysis.metrics import trace_from_records  # noqa: PLC0415

    sc = parse_scenario(scenario_table(args.robots, 1.0 / args.rate, args.duration, 0.5 * args.duration))
    rid = new_run_id(f"bench-latency-{args.robots}")
    outcome = run_fleet(sc, RunOptions(out_dir=root / rid, run_id=rid, progress=False, start_timeout_s=600.0))
    trace = trace_from_records(outcome.records, Keys(rid))
    agents = [s for p, s in trace.stats.items() if p != "sim"]
    p50 = sorted(s["peer_age_ms_p50"] for s in agents if "peer_age_ms_p50" in s)
    p99 = [s["peer_age_ms_p99"] for s in agents if "peer_age_ms_p99" in s]
    mx = [s["peer_age_ms_max"] for s in agents if "peer_age_ms_max" in s]
    robots = (outcome.metrics or {}).get("robots") or {}
    step99 = [r["solve_ms_p99"] for r in robots.values() if r.get("solve_ms_p99") is not None]
    return {"robots": args.robots, "rate_hz": args.rate, "ok": outcome.ok, "reason": outcome.reason,
            "age_ms_p50": p50[len(p50) // 2] if p50 else None, "age_ms_p99_worst": max(p99) if p99 else None,
            "age_ms_max": max(mx) if mx else None, "step_ms_p99_worst": max(step99) if step99 else None,
            "deadline_misses": ((outcome.metrics or {}).get("fleet") or {}).get("deadline_misses")}


def _recorder(args: argparse.Namespace, root: pathlib.Path, views: bool) -> dict[str, Any]:
    from copath.scenario import load_scenario  # noqa: PLC0415
    from copath.wire.keys import Keys  # noqa: PLC0415
    from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint  # noqa: PLC0415

    from orchestrator.run.supervisor import REPO_ROOT  # noqa: PLC0415
    from orchestrator.log.writer import Recorder  # noqa: PLC0415
    from orchestrator.view.foxglove import RecordedViews  # noqa: PLC0415

    run_id = f"bench-recorder-{int(time.time())}"
    keys = Keys(run_id)
    endpoint = loopback_endpoint(free_port())
    scenario = load_scenario(REPO_ROOT / "configs" / "e5.4-six-robots-lemniscate.toml")
    first: list[float] = []
    last = [0.0]
    router = ZenohLink.open(SessionConfig(mode="router", listen=(endpoint,)))
    recorder = Recorder(root / f"recorder-{views}.mcap", keys, {})
    if views:
        RecordedViews(recorder, scenario)
    target = keys.peer_broadcast("r1")

    def write(key: str, data: bytes) -> None:
        recorder.write(key, data)
        if key == target:
            now = time.perf_counter()
            if not first:
                first.append(now)
            last[0] = now

    router.subscribe_raw(keys.all, write)
    proc = subprocess.Popen([sys.executable, "-c", _PUBLISHER, endpoint, run_id, str(args.messages)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=str(REPO_ROOT))
    out = ""
    try:
        out = proc.stdout.readline()  # the publisher's rate: it has put every message
        deadline = time.monotonic() + 30.0 + args.messages / 5000
        while recorder.count_by_key.get(target, 0) < args.messages and time.monotonic() < deadline:
            if proc.poll() is not None:
                break
            time.sleep(0.05)
        got = recorder.count_by_key.get(target, 0)
        proc.stdin.write("\n")
        proc.stdin.flush()
        proc.wait(timeout=10)
    except (subprocess.TimeoutExpired, OSError):
        got = recorder.count_by_key.get(target, 0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
    router.close()
    recorder.finish()
    span = last[0] - first[0] if first else 0.0
    try:
        pub_rate = float(out.strip().splitlines()[-1])
    except (ValueError, IndexError):
        pub_rate = None
    return {"views": views, "messages": args.messages, "recorded": got, "lost": args.messages - got,
            "publisher_msg_s": round(pub_rate) if pub_rate else None,
            "recorder_msg_s": round(got / span) if span > 0 else None}


def _table(result: dict[str, Any]) -> None:
    if result.get("fleet"):
        f = result["fleet"]
        print(f"neighbour-message age on arrival, realtime consensus fleet of {f['robots']} robots at "
              f"{f['rate_hz']:.0f} Hz [ms] (sender's step + transport)")
        print_table([f], [("age_ms_p50", "p50", ".2f"), ("age_ms_p99_worst", "worst agent p99", ".2f"),
                          ("age_ms_max", "max", ".2f"), ("step_ms_p99_worst", "step p99", ".2f"),
                          ("deadline_misses", "deadline misses", "d")])
        if not f["ok"]:
            print(f"fleet run failed: {f['reason']}")
    if result.get("recorder"):
        print("recorder throughput (one publisher process -> router -> recorder; views: Foxglove views built too)")
        print_table(result["recorder"], [("views", "views", ""), ("messages", "messages", "d"), ("recorded", "recorded", "d"),
                                           ("lost", "lost", "d"), ("publisher_msg_s", "publisher msg/s", "d"),
                                           ("recorder_msg_s", "recorder msg/s", "d")])


def run(args: argparse.Namespace) -> int:
    result: dict[str, Any] = {}
    with scratch_dir(None, "latency") as root:
        if not args.no_fleet:
            result["fleet"] = _fleet(args, root)
        if not args.no_recorder:
            result["recorder"] = [_recorder(args, root, views) for views in (False, True)]
    emit(args, result, _table)
    ok = (result.get("fleet") or {}).get("ok", True) and all(r["lost"] == 0 for r in result.get("recorder") or ())
    return 0 if ok else 1
