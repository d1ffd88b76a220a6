"""Live views: the run's Foxglove views served over the Foxglove WebSocket protocol.

``copath run --live [PORT]`` hands every view the recorder builds (orchestrator/view/foxglove.py)
to a :class:`LiveViz` as well, so Foxglove (``Open connection`` -> ``Foxglove WebSocket``
-> ``ws://localhost:PORT``) shows the fleet while it moves; ``copath replay --live``
feeds the views of a recorded run with its original timing (:func:`serve_log`). The
server is ``foxglove-sdk``'s (``foxglove.start_server``) on its own context, so nothing
else in the process logs to it. See docs/reference/viewing.md.
"""

from __future__ import annotations

import pathlib
import threading
import time

import foxglove
from foxglove import channels as fc

from copath.scenario import parse_scenario
from copath.wire.keys import Keys
from copath.wire.messages import WireError, unpack

from orchestrator.log.mcap import iter_raw, read_log
from orchestrator.view.foxglove import VizBuilder, log_line

__all__ = ["LiveViz", "LivePortError", "LogTail", "DEFAULT_PORT", "serve_log"]

DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""


class LivePortError(ValueError):
    """The live server cannot listen on the port asked for."""


class LiveViz:
    """A Foxglove WebSocket server; :meth:`log` is a view sink (thread-safe)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "copath") -> None:
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except RuntimeError as exc:  # foxglove-sdk reports a bind failure as a RuntimeError
            raise LivePortError(f"--live = {port} is not allowed; the port cannot be opened ({exc}); "
                                "choose a free one with --live PORT") from None
        self._channels: dict[str, object] = {}
        self._lock = threading.Lock()
        self.count = 0

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://localhost:{self.port}"

    def advertise(self, topics: dict[str, type]) -> None:
        """Create channels up front so clients see them before the first message."""
        for topic, cls in topics.items():
            self._channel(topic, cls)

    def _channel(self, topic: str, cls: type):
        with self._lock:
            ch = self._channels.get(topic)
            if ch is None:
                ch = getattr(fc, f"{cls.__name__}Channel")(topic, context=self.context)
                self._channels[topic] = ch
            return ch

    def log(self, topic: str, msg, log_time_ns: int) -> None:
        self._channel(topic, type(msg)).log(msg, log_time=int(log_time_ns))
        self.count += 1

    def close(self) -> None:
        self.server.stop()


class LogTail:
    """Follows the processes' logs (``log_dir/*.log``) and hands each new complete line to
    ``sink`` as ``foxglove.Log`` on ``/viz/log`` while a run goes on (the recorder writes
    the whole logs into ``run.mcap`` at the end of the run)."""

    def __init__(self, log_dir: str | pathlib.Path, sink, period_s: float = 0.5) -> None:
        self.dir = pathlib.Path(log_dir)
        self.sink = sink
        self.period_s = period_s
        self._pos: dict[pathlib.Path, int] = {}
        self._last: dict[pathlib.Path, int] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="copath-log-tail", daemon=True)
        self.lines = 0

    def start(self) -> "LogTail":
        self._thread.start()
        return self

    def poll(self) -> int:
        """Send the lines completed since the last poll; returns how many."""
        n = 0
        for f in sorted(self.dir.glob("*.log")):
            pos = self._pos.get(f, 0)
            try:
                with f.open("rb") as fh:
                    fh.seek(pos)
                    chunk = fh.read()
            except OSError:
                continue
            end = chunk.rfind(b"\n")
            if end < 0:
                continue
            self._pos[f] = pos + end + 1
            for raw in chunk[:end].decode(errors="replace").splitlines():
                if raw.strip():
                    t, msg = log_line(raw, f.stem, self._last.get(f, time.time_ns()))
                    self._last[f] = t
                    self.sink.log("/viz/log", msg, t)
                    n += 1
        self.lines += n
        return n

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.poll()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.poll()


def serve_log(mcap_path: str | pathlib.Path, live: LiveViz, *, speed: float = 1.0,
              stop: threading.Event | None = None) -> int:
    """Feed the views of a recorded run to ``live`` with the log's timing divided by
    ``speed`` (``speed <= 0``: as fast as possible); returns the number of views sent."""
    path = pathlib.Path(mcap_path)
    log = read_log(path)  # metadata only is needed; read_log also validates the file
    raw = log.scenario_raw
    if not raw:
        raise ValueError(f"{path}: no scenario in the log metadata (not a copath run log?)")
    builder = VizBuilder(parse_scenario(raw, source=str(raw.get("_source", ""))), Keys(log.run_id or "run"))
    wall0, t0 = time.monotonic(), None
    sent = 0
    for topic, msg in builder.static():
        live.log(topic, msg, time.time_ns())
        sent += 1
    for t_ns, key, data in iter_raw(path):
        if stop is not None and stop.is_set():
            break
        try:
            rec = unpack(data)
        except WireError:
            continue
        t0 = t_ns if t0 is None else t0
        if speed > 0:
            wait = (t_ns - t0) / 1e9 / speed - (time.monotonic() - wall0)
            if wait > 0:
                time.sleep(wait)
        for topic, msg in builder.feed(key, rec):
            live.log(topic, msg, time.time_ns())
            sent += 1
    return sent
