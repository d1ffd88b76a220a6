"""``copath info`` and ``copath replay``: look into a run log, or put it back on Zenoh.

``info`` prints channels, message counts, duration, robots and the scenario (like
``ros2 bag info``). ``replay`` republishes every recorded message on its original key
(optionally under another run id) with the original timing scaled by ``speed``, so a
viewer or another tool can consume a past run live. Without ``--connect`` it hosts its
own router on a free loopback port and prints the endpoint.

``--wait-for N`` holds the first message back until N sessions have joined the replay's
router and a subscriber matches the log's keys (``--wait-for 2.5s``: a fixed delay), so a
client that connects just after the start hears everything. ``--pace sim`` spaces the
messages by the simulated time of the tick they belong to (a lockstep log, recorded
faster than real time, replays in real time), ``--pace wall`` (default) by the recorded
wall time. ``--record OUT.mcap`` writes what was republished to a new log.
"""

from __future__ import annotations

import bisect
import json
import pathlib
import re
import sys
import time
from dataclasses import dataclass

from mcap.reader import make_reader

from copath.wire.keys import ROOT, valid_run_id
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint

from orchestrator.log.mcap import LogError, check_log, iter_raw, read_metadata, require_copath

__all__ = ["log_info", "format_info", "replay", "ReplayResult"]


def log_info(path: str | pathlib.Path) -> dict:
    """Summary of a run log as a dict (what ``copath info`` prints).

    Raises FileNotFoundError, or :class:`~orchestrator.log.mcap.LogError` (a ValueError)
    for an empty, non-MCAP or foreign file. A log cut short (``cut_short``) is read up to
    its last complete chunk; its Foxglove views are not counted."""
    path = pathlib.Path(path)
    chk = check_log(path)
    metadata = read_metadata(path)
    require_copath(path, metadata)
    channels, viz = {}, {}
    if chk.cut_short:
        times = []
        for t, key, _ in iter_raw(path):
            channels[key] = channels.get(key, 0) + 1
            times.append(t)
        start, end, count = (min(times), max(times), len(times)) if times else (0, 0, 0)
        outcome = {"ok": "False", "reason": "cut short: the log ends before its footer (the recorder was "
                                            f"stopped before closing it); {count} messages read up to its last "
                                            "complete chunk"}
    else:
        try:
            with path.open("rb") as fh:
                summary = make_reader(fh).get_summary()
        except Exception as exc:  # a damaged footer or summary
            raise LogError(f"{path}: the MCAP summary is damaged ({type(exc).__name__}: {exc})") from None
        if summary is None or summary.statistics is None:
            raise LogError(f"{path}: the MCAP file has no summary section")
        st = summary.statistics
        for cid, ch in summary.channels.items():
            (channels if ch.message_encoding == "msgpack" else viz)[ch.topic] = st.channel_message_counts.get(cid, 0)
        start, end, count = st.message_start_time, st.message_end_time, st.message_count
        outcome = metadata.get("outcome", {})
    scen = json.loads(metadata.get("scenario", {}).get("json", "{}") or "{}")
    return {
        "file": path.name,
        "size_bytes": path.stat().st_size,
        "messages": sum(channels.values()),
        "channels": dict(sorted(channels.items())),
        "viz_channels": dict(sorted(viz.items())),
        "start_ns": start,
        "end_ns": end,
        "duration_s": (end - start) / 1e9 if count else 0.0,
        "cut_short": chk.cut_short,
        "run_id": metadata.get("copath", {}).get("run_id"),
        "version": metadata.get("copath", {}).get("version"),
        "clock": metadata.get("copath", {}).get("clock"),
        "robots": [r for r in metadata.get("copath", {}).get("robots", "").split(",") if r],
        "scenario_id": scen.get("id"),
        "scenario_title": scen.get("title"),
        "outcome": outcome,
        "scenario": scen,
    }


def format_info(info: dict) -> str:
    lines = [
        f"Files:        {info['file']}",
        f"Size:         {info['size_bytes'] / 1024:.1f} KiB",
        f"Run id:       {info['run_id']}",
        f"copath:       {info['version']}",
        f"Scenario:     {info['scenario_id']}  {info['scenario_title'] or ''}",
        f"Clock:        {info['clock']}",
        f"Robots:       {', '.join(info['robots'])}",
        f"Outcome:      {info['outcome'].get('ok', '?')}  {info['outcome'].get('reason', '')}",
        f"Duration:     {info['duration_s']:.3f} s (wall clock, first to last message of the log)",
        f"Messages:     {info['messages']}",
        f"Channels:     {len(info['channels'])}",
    ]
    width = max((len(k) for k in info["channels"]), default=10)
    for topic, n in info["channels"].items():
        lines.append(f"  {topic:<{width}}  {n:>8d} msgs  (msgpack)")
    for topic, n in info.get("viz_channels", {}).items():
        lines.append(f"  {topic:<{width}}  {n:>8d} msgs  (Foxglove view)")
    return "\n".join(lines)


@dataclass
class ReplayResult:
    published: int
    endpoint: str
    duration_s: float


def _rekey(key: str, new_run: str | None) -> str:
    if not new_run:
        return key
    parts = key.split("/", 2)
    if len(parts) == 3 and parts[0] == ROOT:
        return f"{ROOT}/{new_run}/{parts[2]}"
    return key


def parse_wait_for(spec: str | None) -> tuple[int, float]:
    """``"3"`` -> (3 sessions, 0 s); ``"2.5s"`` -> (0, 2.5 s); None -> (0, 0)."""
    if spec is None:
        return 0, 0.0
    s = str(spec).strip()
    if re.fullmatch(r"\d+", s):
        return int(s), 0.0
    m = re.fullmatch(r"(\d+(?:\.\d*)?)s", s)
    if m:
        return 0, float(m.group(1))
    raise ValueError(f"--wait-for = {spec!r} is not allowed; give a number of sessions (e.g. 2) or a delay "
                     "in seconds (e.g. 2.5s)")


def _sim_clock(path: pathlib.Path):
    """log time [ns] -> simulated time [s] of the tick the message belongs to (the first
    truth record at or after it; after the last truth, the last one's time)."""
    import msgpack  # noqa: PLC0415

    times, sims = [], []
    for t, key, data in iter_raw(path):
        if key.endswith("/sim/truth"):
            try:
                times.append(t)
                sims.append(float(msgpack.unpackb(data)["t"]))
            except Exception:  # a damaged truth record: skip it
                times.pop()
    if not times:
        raise LogError(f"{path}: --pace sim needs the simulator's truth records, and the log has none")

    def sim_time(t_ns: int) -> float:
        i = min(bisect.bisect_left(times, t_ns), len(times) - 1)
        return sims[i]

    return sim_time


def _await_audience(link: ZenohLink, sessions: int, delay_s: float, timeout_s: float, key: str) -> None:
    """Wait until ``sessions`` sessions are connected and a subscriber matches ``key``, then ``delay_s``."""
    if sessions > 0:
        deadline = time.monotonic() + timeout_s
        pub = link.session.declare_publisher(key)
        try:
            while len(list(link.session.info.transports())) < sessions or not pub.matching_status.matching:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"--wait-for {sessions}: {len(list(link.session.info.transports()))} "
                                       f"session(s) joined within {timeout_s:.0f} s")
                time.sleep(0.02)
        finally:
            pub.undeclare()
    if delay_s > 0:
        time.sleep(delay_s)


def replay(path: str | pathlib.Path, *, speed: float = 1.0, run_id: str | None = None,
           connect: tuple[str, ...] = (), listen: tuple[str, ...] = (), start_delay_s: float = 0.5,
           announce=None, wait_for: str | None = None, wait_timeout_s: float = 120.0, pace: str = "wall",
           record: str | pathlib.Path | None = None) -> ReplayResult:
    """Republish a run log on Zenoh with its original timing divided by ``speed``."""
    if not speed > 0:
        raise ValueError(f"--speed = {speed!r} is not allowed; must be > 0")
    if pace not in ("wall", "sim"):
        raise ValueError(f"--pace = {pace!r} is not allowed; allowed: wall, sim")
    sessions, delay_s = parse_wait_for(wait_for)
    if run_id:
        valid_run_id(run_id)
    path = pathlib.Path(path)
    check_log(path)
    metadata = read_metadata(path)
    require_copath(path, metadata)
    sim_time = _sim_clock(path) if pace == "sim" else None
    if connect:
        conf = SessionConfig(mode="client", connect=tuple(connect), listen=tuple(listen))
        endpoint = connect[0]
    else:
        endpoint = listen[0] if listen else loopback_endpoint(free_port())
        conf = SessionConfig(mode="router", listen=(endpoint,))
    n = 0
    recorder = None
    if record is not None:
        from copath.wire.keys import Keys  # noqa: PLC0415

        from orchestrator.log.writer import Recorder  # noqa: PLC0415

        new_id = run_id or metadata.get("copath", {}).get("run_id", "replay")
        meta = {k: dict(v) for k, v in metadata.items() if k != "outcome"}
        meta.setdefault("copath", {})["run_id"] = new_id
        meta["replay"] = {"source": str(path), "pace": pace, "speed": str(speed)}
        recorder = Recorder(pathlib.Path(record), Keys(new_id), meta)
    with ZenohLink.open(conf) as link:
        if announce:
            announce(endpoint)
        if sessions or delay_s:
            run = run_id or metadata.get("copath", {}).get("run_id") or "*"
            _await_audience(link, sessions, delay_s, wait_timeout_s, f"{ROOT}/{run}/**")
        else:
            time.sleep(start_delay_s)  # give subscribers a moment to connect
        t0_wall = time.monotonic()
        t0_log = None
        last = 0.0
        for log_time, key, data in iter_raw(path):
            clock = sim_time(log_time) * 1e9 if sim_time is not None else log_time
            if t0_log is None:
                t0_log = clock
            due = (clock - t0_log) / 1e9 / speed
            wait = t0_wall + due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            out_key = _rekey(key, run_id)
            link.publish_bytes(out_key, data)
            if recorder is not None:
                recorder.write(out_key, data)
            n += 1
            last = due
        time.sleep(0.2)
    if recorder is not None:
        recorder.finish({"outcome": {"ok": "True", "reason": f"replay of {path.name}"}})
    return ReplayResult(n, endpoint, last)


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2)
    sys.stdout.write("\n")
