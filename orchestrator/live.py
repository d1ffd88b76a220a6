"""Live views: the run's Foxglove views served over the Foxglove WebSocket protocol.

``copath run --live [PORT]`` hands every view the recorder builds (orchestrator/viz.py)
to a :class:`LiveViz` as well, so Foxglove (``Open connection`` -> ``Foxglove WebSocket``
-> ``ws://localhost:PORT``) shows the fleet while it moves; ``copath replay --live``
feeds the views of a recorded run with its original timing (:func:`serve_log`). The
server is ``foxglove-sdk``'s (``foxglove.start_server``) on its own context, so nothing
else in the process logs to it. See docs/viewing.md.
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

from .mcaplog import iter_raw, read_log
from .viz import VizBuilder

__all__ = ["LiveViz", "DEFAULT_PORT", "serve_log"]

DEFAULT_PORT = 8765
"""Foxglove's default WebSocket port."""


class LiveViz:
    """A Foxglove WebSocket server; :meth:`log` is a view sink (thread-safe)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "copath") -> None:
        self.context = foxglove.Context()
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
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
