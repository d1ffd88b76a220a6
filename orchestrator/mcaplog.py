"""MCAP run logs: the recorder that writes them and the reader that reads them back.

Every message under the run prefix lands in ``run.mcap`` unchanged (msgpack encoding,
schema id 0, one channel per key, zstd chunks), stamped with its receive time. The
effective scenario (JSON) and the software version are MCAP metadata, so a run is
explainable from its log alone.
"""

from __future__ import annotations

import json
import pathlib
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Iterator

from mcap.reader import make_reader
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, Writer

from copath.wire.keys import Keys
from copath.wire.messages import End, Stats, Truth, WireError, unpack

__all__ = ["Recorder", "RunLog", "read_log", "iter_raw", "software_version"]


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("copath")
    except Exception:
        return "0+unknown"


class Recorder:
    """Writes every (key, bytes) it is given to an MCAP file; thread-safe."""

    def __init__(self, path: pathlib.Path, keys: Keys, metadata: dict[str, dict[str, str]],
                 scenario=None) -> None:
        self.path = pathlib.Path(path)
        self.keys = keys
        self._fh = self.path.open("wb")
        self._w = Writer(self._fh, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"copath {software_version()}")
        self._metadata = metadata
        self._channels: dict[str, int] = {}
        self._lock = threading.Lock()
        self.count = 0
        self.count_by_key: dict[str, int] = {}
        self.sim_t = 0.0
        self.stats: dict[str, Stats] = {}
        self.end: End | None = None
        self._closed = False
        self._viz: dict[str, int] = {}
        self._radii = {}
        if scenario is not None:  # Foxglove channels derived from the truth (orchestrator/viz.py)
            from . import viz

            self._vizmod = viz
            self._radii = {r.name: r.model.radius for r in scenario.robots}
            for topic, schema_name in viz.TOPICS.items():
                sid = self._w.register_schema(schema_name, "jsonschema", json.dumps(viz.SCHEMAS[schema_name]).encode())
                self._viz[topic] = self._w.register_channel(topic=topic, message_encoding=MessageEncoding.JSON,
                                                            schema_id=sid)
            self._w.add_message(self._viz["/viz/scene"], log_time=time.time_ns(), data=viz.static_scene(scenario),
                                publish_time=time.time_ns(), sequence=0)

    def write(self, key: str, data: bytes) -> None:
        now = time.time_ns()
        rel = self.keys.relative(key)
        with self._lock:
            if self._closed:
                return
            ch = self._channels.get(key)
            if ch is None:
                ch = self._w.register_channel(topic=key, message_encoding=MessageEncoding.MessagePack, schema_id=0)
                self._channels[key] = ch
            self.count += 1
            n = self.count_by_key.get(key, 0) + 1
            self.count_by_key[key] = n
            self._w.add_message(ch, log_time=now, data=data, publish_time=now, sequence=n)
        # light decoding for progress and the closing account
        if rel == "sim/truth" or rel.startswith("stats/") or rel == "sim/end":
            try:
                rec = unpack(data)
            except WireError:
                return
            if isinstance(rec, Truth):
                self.sim_t = rec.t
                if self._viz:
                    scene = self._vizmod.scene_update(rec, self._radii)
                    poses = self._vizmod.poses_in_frame(rec)
                    with self._lock:
                        if not self._closed:
                            self._w.add_message(self._viz["/viz/scene"], log_time=now, data=scene, publish_time=now)
                            self._w.add_message(self._viz["/viz/robots"], log_time=now, data=poses, publish_time=now)
            elif isinstance(rec, Stats):
                self.stats[rec.proc] = rec
            elif isinstance(rec, End):
                self.end = rec

    def finish(self, extra_metadata: dict[str, dict[str, str]] | None = None) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for name, data in {**self._metadata, **(extra_metadata or {})}.items():
                self._w.add_metadata(name, {k: str(v) for k, v in data.items()})
            self._w.finish()
            self._fh.close()


@dataclass
class RunLog:
    """A run log read back: decoded records plus metadata."""

    records: list[tuple[int, str, Any]]
    metadata: dict[str, dict[str, str]]
    rejected: int = 0
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def run_id(self) -> str:
        return self.metadata.get("copath", {}).get("run_id", "")

    @property
    def scenario_raw(self) -> dict:
        return json.loads(self.metadata.get("scenario", {}).get("json", "{}"))


def iter_raw(path: str | pathlib.Path) -> Iterator[tuple[int, str, bytes]]:
    """(log_time_ns, key, bytes) of every run message (msgpack) in log order; the derived
    Foxglove channels are left out."""
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == MessageEncoding.MessagePack:
                yield message.log_time, channel.topic, message.data


def read_log(path: str | pathlib.Path) -> RunLog:
    """Read and decode a run log (records that fail validation are counted, not raised)."""
    records = []
    rejected = 0
    counts: dict[str, int] = {}
    for t, key, data in iter_raw(path):
        counts[key] = counts.get(key, 0) + 1
        try:
            records.append((t, key, unpack(data)))
        except WireError:
            rejected += 1
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return RunLog(records, metadata, rejected, counts)
