"""``copath bench floor``: the floor of a lockstep fleet over Zenoh, against IR-SIM's rate.

    copath bench floor [--robots 6] [--ticks 2000] [--receive callback direct thread fifo]
                       [--puts 1] [--overhear] [--no-recorder] [--fleet] [--no-irsim] [--json]

Issue 22 asks a lockstep fleet (one process per robot, a simulator process, a recorder,
Zenoh) for half IR-SIM's speed. This harness measures what the design reaches when the
robots do nothing, in two ways (docs/journal/performance.md, the floor of the design (P26)):

1. **Bare Zenoh round trips** (``ping``): this process hosts a router (and, unless
   ``--no-recorder``, a subscriber to every key that counts the samples, as the run's
   recorder does); one ``sim`` process publishes a tick to each of ``--robots`` ``agent``
   processes (one key each, like the observations) and waits until every agent has
   answered with ``--puts`` records (the last one its command); then the next tick. With
   ``--overhear`` an agent's first record is a broadcast that every other agent receives
   (E5.4's traffic with its safety filter, which overhears every robot: ``--overhear
   --puts 3``, a broadcast, telemetry and a command).
   Sessions are configured as copath's (:class:`copath.wire.session.SessionConfig`:
   clients of the router, multicast scouting off, loopback, the 1 s lease), publishers
   with congestion control BLOCK. How an agent receives the tick (``--receive``):

   - ``callback``: it answers inside the Python callback, which zenoh-python runs on a
     Python thread of its own per subscriber (what ``copath/wire/session.py`` declares);
   - ``direct``: the same callback run on Zenoh's network thread itself
     (``zenoh.handlers.Callback(..., indirect=False)``, marked unstable by zenoh-python);
   - ``thread``: the callback hands every sample to the main thread through a
     ``queue.Queue``, which answers (``agent/node.py`` hands its observations over so);
   - ``fifo``: no callback; the main thread drains Zenoh's FIFO channel (``recv()``)
     and answers (the receive path without the per-sample Python thread).

   Figures: ticks per second over ``--ticks`` ticks (after ``--warmup`` ticks), and CPU
   per tick of the simulator, of an agent (p50 over agents) and of this process (router
   and recorder).
2. **The idle fleet** (``--fleet``): E5.4 run as ``copath run`` does (the same path as
   ``copath bench fleet``) with the safety filter and the detours off (``safety.enabled``,
   ``safety.detours``: robots that stand still would otherwise plan detours round each
   other, the stage's stall rule) and, in place of the consensus law,
   :mod:`orchestrator.studies.bench.idle`: a constant command (zero: they stand still),
   with and without one small message per step. Figures: the fleet's real-time factor
   while ticking (start-up left out) and the agents' CPU per step from their closing
   accounts: copath's own floor, its simulator, runtime, records and recorder included.

And IR-SIM (``copath bench peers``' world, 6 robots, step 0.1 s) in the same run, unless
``--no-irsim``, so each floor is given as a ratio to IR-SIM's steps per second (the idle
fleet's while ticking): a floor below 0.5 puts issue 22's goal out of the design's reach on
this machine. The ratios follow IR-SIM's own scatter under load; the CPU figures move less.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import queue
import signal
import subprocess
import sys
import threading
import time
from typing import Any

from orchestrator.studies.bench.harness import emit, number, print_table, scratch_dir

__all__ = ["add_arguments", "run", "ping", "idle_fleet", "RECEIVE"]

RECEIVE = ("callback", "direct", "thread", "fifo")
"""How an agent of the bare harness receives a tick (see the module's docstring)."""

TICK_BYTES = 240
"""Size of a tick (an observation of E5.4 packs to about this much) [bytes]."""
REPLY_BYTES = 120
"""Size of each record an agent answers with [bytes]."""
FIFO_CAPACITY = 256
"""Capacity of the FIFO channel in ``fifo`` mode (Zenoh's default)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=number("--robots", int, 1, strict=False), default=6, metavar="N",
                        help="agent processes [6]")
    parser.add_argument("--ticks", type=number("--ticks", int, 1, strict=False), default=2000, metavar="K",
                        help="timed ticks of the bare harness [2000]")
    parser.add_argument("--warmup", type=number("--warmup", int, 0, strict=False), default=100, metavar="K",
                        help="ticks before the timing starts [100]")
    parser.add_argument("--receive", nargs="+", default=list(RECEIVE), choices=RECEIVE,
                        help="how agents receive a tick, one run each [callback direct thread fifo]")
    parser.add_argument("--puts", type=number("--puts", int, 1, strict=False), default=1, metavar="P",
                        help="records each agent publishes per tick, the command last [1]")
    parser.add_argument("--overhear", action="store_true",
                        help="each agent's first record is a broadcast every other agent receives "
                             "(E5.4's filter overhears every robot)")
    parser.add_argument("--no-recorder", action="store_true", help="no subscriber to every key in the router's process")
    parser.add_argument("--fleet", action="store_true",
                        help="also E5.4 as copath run: idle controller, filter and detours off, with and without messages")
    parser.add_argument("--no-irsim", action="store_true", help="leave IR-SIM out (no ratios)")
    parser.add_argument("--timeout", type=float, default=300.0, metavar="S", help="give up a bare run after this [300]")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


# -- the processes of the bare harness ---------------------------------------------------


def _session(endpoint: str):
    from copath.wire.session import SessionConfig, open_session  # noqa: PLC0415

    return open_session(SessionConfig(mode="client", connect=(endpoint,)))


def _cpu() -> float:
    """This process's CPU time, every thread (Zenoh's included) [s]."""
    return time.process_time()


def _agent(endpoint: str, prefix: str, index: int, warmup: int, ticks: int, receive: str, puts: int,
           overhear: bool = False) -> dict[str, Any]:
    """One agent: answer every tick with ``puts`` records; CPU over the timed ticks. With
    ``overhear`` the first record goes on ``peer/<index>/all`` and the agent receives every
    other agent's (counted, in the same way it receives a tick)."""
    import zenoh  # noqa: PLC0415

    session = _session(endpoint)
    decls: list[Any] = []
    try:
        keys = [f"{prefix}/robot/{index}/out/{j}" for j in range(puts)]
        if overhear:
            keys[0] = f"{prefix}/peer/{index}/all"
        pubs = [session.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK,
                                          allowed_destination=zenoh.Locality.REMOTE) for k in keys]
        decls.extend(pubs)
        reply = b"p" + bytes(REPLY_BYTES - 1) if overhear else bytes(REPLY_BYTES)
        last = warmup + ticks - 1
        acct: dict[str, float] = {}
        done = threading.Event()

        def answer(payload: bytes) -> None:
            if payload[8:9] == b"p":  # a neighbour's broadcast: received, nothing else
                return
            k = int.from_bytes(payload[:8], "little")
            if k == warmup:
                acct["cpu0"] = _cpu()
            for pub in pubs:
                pub.put(payload[:8] + reply)  # a tick starts with 8 bytes of k, then zeros
            if k == last:
                acct["cpu1"] = _cpu()
                done.set()

        key = f"{prefix}/robot/{index}/obs"
        peers = f"{prefix}/peer/*/all"
        token = f"{prefix}/alive/{index}"
        sim_gone = threading.Event()
        decls.append(session.liveliness().declare_subscriber(
            f"{prefix}/alive/sim", history=True,
            handler=lambda s: sim_gone.set() if s.kind == zenoh.SampleKind.DELETE else None))
        if receive in ("callback", "direct"):
            def on_sample(s) -> None:
                answer(s.payload.to_bytes())

            indirect = receive == "callback"  # False: on Zenoh's network thread
            decls.append(session.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=indirect)))
            if overhear:
                decls.append(session.declare_subscriber(peers, zenoh.handlers.Callback(on_sample, indirect=indirect)))
            decls.append(session.liveliness().declare_token(token))
            done.wait()
        elif receive == "thread":
            q: queue.Queue = queue.Queue()
            decls.append(session.declare_subscriber(key, lambda s: q.put(s.payload.to_bytes())))
            if overhear:
                decls.append(session.declare_subscriber(peers, lambda s: q.put(s.payload.to_bytes())))
            decls.append(session.liveliness().declare_token(token))
            while not done.is_set():
                answer(q.get())
        else:  # fifo: the main thread drains Zenoh's channels, no Python callback thread
            sub = session.declare_subscriber(key, zenoh.handlers.FifoChannel(FIFO_CAPACITY))
            decls.append(sub)
            psub = session.declare_subscriber(peers, zenoh.handlers.FifoChannel(FIFO_CAPACITY)) if overhear else None
            if psub is not None:
                decls.append(psub)
            decls.append(session.liveliness().declare_token(token))
            while not done.is_set():
                answer(sub.recv().payload.to_bytes())  # a tick wakes the step ...
                while psub is not None and (got := psub.try_recv()) is not None:  # ... which drains the rest
                    answer(got.payload.to_bytes())
        sim_gone.wait(timeout=10.0)  # the last answers are on their way when the simulator has them
        return {"cpu_s": acct["cpu1"] - acct["cpu0"]}
    finally:
        for d in reversed(decls):
            d.undeclare()
        session.close()


def _sim(endpoint: str, prefix: str, robots: int, warmup: int, ticks: int, puts: int) -> dict[str, Any]:
    """The simulator: tick every agent, wait for all their records, repeat; time the ticks."""
    import zenoh  # noqa: PLC0415

    session = _session(endpoint)
    decls: list[Any] = []
    try:
        alive: set[str] = set()
        up = threading.Condition()

        def on_alive(sample) -> None:
            with up:
                (alive.add if sample.kind == zenoh.SampleKind.PUT else alive.discard)(str(sample.key_expr))
                up.notify()

        decls.append(session.liveliness().declare_subscriber(f"{prefix}/alive/*", history=True, handler=on_alive))
        got = [0]
        answered = threading.Condition()

        def on_reply(sample) -> None:
            with answered:
                got[0] += 1
                if got[0] >= robots * puts:
                    answered.notify()

        decls.append(session.declare_subscriber(f"{prefix}/robot/*/out/*", on_reply))
        decls.append(session.declare_subscriber(f"{prefix}/peer/*/all", on_reply))
        pubs = [session.declare_publisher(f"{prefix}/robot/{i}/obs", congestion_control=zenoh.CongestionControl.BLOCK)
                for i in range(robots)]
        decls.extend(pubs)
        decls.append(session.liveliness().declare_token(f"{prefix}/alive/sim"))  # agents leave when it goes
        with up:
            if not up.wait_for(lambda: len([a for a in alive if not a.endswith("/sim")]) >= robots, timeout=60.0):
                raise RuntimeError(f"only {len(alive)} of {robots} agents came up within 60 s")
        tick = bytearray(TICK_BYTES)
        t0 = c0 = 0.0
        for k in range(warmup + ticks):
            if k == warmup:
                t0, c0 = time.perf_counter(), _cpu()
            tick[:8] = k.to_bytes(8, "little")
            with answered:
                got[0] = 0
            data = bytes(tick)
            for pub in pubs:
                pub.put(data)
            with answered:
                if not answered.wait_for(lambda: got[0] >= robots * puts, timeout=10.0):
                    raise RuntimeError(f"tick {k}: {got[0]} of {robots * puts} answers within 10 s")
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        return {"wall_s": wall, "cpu_s": cpu}
    finally:
        for d in reversed(decls):
            d.undeclare()
        session.close()


def _child_main(argv: list[str]) -> int:
    """``python -m orchestrator.studies.bench.floor sim|agent ...``: one process of the bare harness;
    prints its figures as one JSON line."""
    p = argparse.ArgumentParser(prog="floor child")
    p.add_argument("role", choices=("sim", "agent"))
    p.add_argument("--endpoint", required=True)
    p.add_argument("--prefix", required=True)
    p.add_argument("--index", type=int, default=0)
    p.add_argument("--robots", type=int, required=True)
    p.add_argument("--warmup", type=int, required=True)
    p.add_argument("--ticks", type=int, required=True)
    p.add_argument("--receive", choices=RECEIVE, default="callback")
    p.add_argument("--puts", type=int, default=1)
    p.add_argument("--overhear", action="store_true")
    a = p.parse_args(argv)
    if a.role == "sim":
        out = _sim(a.endpoint, a.prefix, a.robots, a.warmup, a.ticks, a.puts)
    else:
        out = _agent(a.endpoint, a.prefix, a.index, a.warmup, a.ticks, a.receive, a.puts, a.overhear)
    print(json.dumps(out), flush=True)
    return 0


def _stop(procs: list[subprocess.Popen]) -> None:
    """Stop what is still running of ``procs``, each by its own process group."""
    for p in procs:
        if p.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    for p in procs:
        try:
            p.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.wait()


def ping(robots: int = 6, ticks: int = 2000, warmup: int = 100, receive: str = "callback", puts: int = 1,
         recorder: bool = True, timeout_s: float = 300.0, overhear: bool = False,
         started: list[int] | None = None) -> dict[str, Any]:
    """The bare Zenoh lockstep round trip: one run of the harness (see the module's docstring).

    Every process it starts has a session (process group) of its own and is stopped by it,
    whatever happens; ``started`` (if given) receives their pids as they start."""
    from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint  # noqa: PLC0415

    if receive not in RECEIVE:
        raise ValueError(f"receive = {receive!r} is not allowed; allowed: {', '.join(RECEIVE)}")
    endpoint = loopback_endpoint(free_port())
    prefix = f"floor/{os.getpid()}-{time.monotonic_ns()}"
    router = ZenohLink.open(SessionConfig(mode="router", listen=(endpoint,)))
    recorded = [0]
    if recorder:
        router.subscribe_raw(f"{prefix}/**", lambda key, data: recorded.__setitem__(0, recorded[0] + 1))
    common = ["--endpoint", endpoint, "--prefix", prefix, "--robots", str(robots), "--warmup", str(warmup),
              "--ticks", str(ticks), "--puts", str(puts)] + (["--overhear"] if overhear else [])
    cmd = [sys.executable, "-m", "orchestrator.studies.bench.floor"]
    procs: list[subprocess.Popen] = []
    c0 = _cpu()
    try:
        for role in [["agent", "--index", str(i), "--receive", receive] for i in range(robots)] + [["sim"]]:
            procs.append(subprocess.Popen(cmd + role + common, stdout=subprocess.PIPE, text=True, start_new_session=True))
            if started is not None:
                started.append(procs[-1].pid)
        deadline = time.monotonic() + timeout_s
        outs = []
        for p in procs[::-1]:  # the simulator first: it ends when the last tick is answered
            out, _ = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
            if p.returncode != 0 or not out.strip():
                raise RuntimeError(f"a {'sim' if p is procs[-1] else 'agent'} process exited with {p.returncode}")
            outs.append(json.loads(out.strip().splitlines()[-1]))
    finally:
        _stop(procs)
        router_cpu = _cpu() - c0
        router.close()
    sim, agents = outs[0], sorted(o["cpu_s"] for o in outs[1:])
    return {"receive": receive, "robots": robots, "puts": puts, "overhear": overhear, "recorder": recorder,
            "ticks": ticks,
            "ticks_per_s": round(ticks / sim["wall_s"], 1),
            "tick_ms": round(1e3 * sim["wall_s"] / ticks, 3),
            "sim_cpu_ms_per_tick": round(1e3 * sim["cpu_s"] / ticks, 3),
            "agent_cpu_ms_per_tick": round(1e3 * agents[len(agents) // 2] / ticks, 3),
            "router_cpu_s": round(router_cpu, 2), "recorded": recorded[0] if recorder else None}


def idle_fleet(message: bool, root: pathlib.Path) -> dict[str, Any]:
    """E5.4 as ``copath bench fleet`` runs it, with the idle controller and no safety filter."""
    from orchestrator.studies.bench.fleet import measure  # noqa: PLC0415

    sets = ['controller={type = "orchestrator.studies.bench.idle:build", message = %s}' % str(message).lower(),
            "safety.enabled=false", "safety.detours=false"]
    ns = argparse.Namespace(set=sets, duration=None, no_inprocess=True, no_fleet=False)
    row = measure("e5.4", ns, root)
    row["case"] = f"E5.4 idle, {'one message' if message else 'no message'} per step, filter and detours off"
    return row


def _irsim(root: pathlib.Path, robots: int) -> dict[str, Any]:
    from orchestrator.studies.bench.peers import STEP_S, run_irsim  # noqa: PLC0415

    ir = run_irsim(robots, root)
    ir["irsim_steps_per_s"] = round(ir["irsim_rtf"] / STEP_S, 1)
    return ir


def _table(result: dict[str, Any]) -> None:
    ir = result.get("irsim")
    if ir:
        print(f"IR-SIM, {result['robots']} robots (RVO, one process, step 0.1 s): {ir['irsim_rtf']:.1f}x real time, "
              f"{ir['irsim_steps_per_s']:.0f} steps/s, {ir['irsim_cpu_us_per_step']:.0f} us CPU per robot step")
    print("bare Zenoh lockstep: one sim process ticks N agent processes through a router, each answers")
    print_table(result["ping"], [
        ("receive", "receive", ""), ("robots", "robots", "d"), ("puts", "puts", "d"),
        ("ticks_per_s", "ticks/s", ".0f"), ("tick_ms", "ms/tick", ".3f"), ("over_irsim", "/ IR-SIM", ".2f"),
        ("sim_cpu_ms_per_tick", "sim CPU ms/tick", ".3f"), ("agent_cpu_ms_per_tick", "agent CPU ms/tick", ".3f"),
        ("router_cpu_s", "router CPU s", ".2f"), ("load_1min", "load", ".2f")])
    if result.get("fleet"):
        print("idle E5.4 fleet (copath run's path; constant command, safety filter and detours off)")
        print_table(result["fleet"], [
            ("message", "message", ""), ("fleet_sim_s", "sim s", ".1f"), ("startup_s", "startup s", ".2f"),
            ("fleet_wall_s", "fleet s", ".2f"), ("ticking_rtf", "rtf ticking", ".1f"), ("over_irsim", "/ IR-SIM", ".2f"),
            ("agent_cpu_ms_per_step", "agent CPU ms/step", ".3f"), ("sim_cpu_s", "sim CPU s", ".2f"),
            ("load_1min", "load", ".2f")])


def run(args: argparse.Namespace) -> int:
    ok = True
    result: dict[str, Any] = {"robots": args.robots, "ping": [], "fleet": []}
    with scratch_dir(None, "floor") as root:
        ir = None if args.no_irsim else _irsim(root, args.robots)
        result["irsim"] = ir
        ir_rate = ir["irsim_steps_per_s"] if ir else None
        for receive in args.receive:
            load = os.getloadavg()[0]
            row = ping(args.robots, args.ticks, args.warmup, receive, args.puts, not args.no_recorder, args.timeout,
                       args.overhear)
            row["load_1min"] = round(load, 2)
            row["over_irsim"] = round(row["ticks_per_s"] / ir_rate, 3) if ir_rate else None
            result["ping"].append(row)
        if args.fleet:
            for message in (False, True):
                load = os.getloadavg()[0]
                row = idle_fleet(message, root)
                ok = ok and row["ok"]
                row.update(message=message, load_1min=round(load, 2))
                ticking = row.get("ticking_rtf")
                row["over_irsim"] = round(ticking / ir["irsim_rtf"], 3) if ir and ticking else None
                result["fleet"].append(row)
    emit(args, result, _table)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(_child_main(sys.argv[1:]))
