"""MCAP run logs: the recorder that writes them and the reader that reads them back.

Every message under the run prefix lands in ``run.mcap`` unchanged (msgpack encoding,
schema id 0, one channel per key, zstd chunks), stamped with its receive time. The
effective scenario (JSON) and the software version are MCAP metadata, so a run is
explainable from its log alone. Given the scenario, the recorder also writes the
Foxglove views of the run beside them (``/viz/*`` protobuf channels, orchestrator/view/foxglove.py)
and can hand them to a live server (orchestrator/view/live.py) as they are made.
"""

from __future__ import annotations

import json
import pathlib
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Iterator

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.reader import make_reader
from mcap.records import Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding

from copath.wire.keys import Keys
from copath.wire.messages import End, Stats, Truth, WireError, unpack
from copath.wire.session import read_seq_attachment

__all__ = ["Recorder", "RunLog", "read_log", "iter_raw", "software_version", "write_records", "LogError",
           "check_log", "LogCheck", "read_metadata", "fault_metadata"]

MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes an MCAP file starts and ends with."""


def fault_metadata(scenario) -> dict[str, str]:
    """The run's injected faults as MCAP metadata ``faults`` (JSON per section): the
    robot-to-robot network faults and the sensor noise, so a log says what was injected
    (each drop and partition window is also an event on the timeline; docs/reference/faults.md)."""
    import dataclasses  # noqa: PLC0415

    out = {"network": json.dumps(dataclasses.asdict(scenario.network))}
    if getattr(scenario, "noise", None) is not None:
        out["noise"] = json.dumps(dataclasses.asdict(scenario.noise))
    return out


def software_version() -> str:
    try:
        from importlib.metadata import version

        return version("copath")
    except Exception:
        return "0+unknown"


class Recorder:
    """Writes every (key, bytes) it is given to an MCAP file; thread-safe.

    The file is written by ``foxglove-sdk``'s MCAP writer (Rust): about 2 us per message
    against 9 us for the pure-Python ``mcap`` writer, which held the recorder to 80 k
    messages/s (docs/journal/performance.md, goals of the issue, measured (P9)). Each key is a channel with message
    encoding ``msgpack`` and schema id 0 (self-describing), as the MCAP spec's well-known
    encodings have it; the SDK's public ``Channel`` asks for a schema for any encoding
    but JSON, so the schemaless channel is made by the context the public class uses."""

    def __init__(self, path: pathlib.Path, keys: Keys, metadata: dict[str, dict[str, str]],
                 scenario=None, live=None) -> None:
        self.path = pathlib.Path(path)
        self.keys = keys
        self._ctx = foxglove.Context()
        # 256 KiB chunks (not 1 MiB): a recorder killed mid-run loses at most one chunk (docs/reference/faults.md)
        self._mcap = foxglove.open_mcap(str(self.path), allow_overwrite=True, context=self._ctx,
                                        writer_options=MCAPWriteOptions(compression=MCAPCompression.Zstd,
                                                                        chunk_size=256 * 1024, profile=""))
        self._metadata = metadata
        # the run's metadata goes in first, so a log cut short (the orchestrator killed)
        # still says which run and scenario it holds; the outcome follows at the end
        for name, data in metadata.items():
            self._mcap.write_metadata(name, {k: str(v) for k, v in data.items()})
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self.count = 0
        self.count_by_key: dict[str, int] = {}
        self.last_cmd_ns: dict[str, int] = {}
        self.accounts: dict[tuple[str, int], dict] = {}
        """Per (sender, incarnation): records received, first and last sequence number, the
        numbers missing (gaps), and the closing account's ``published`` when one came."""
        """Receive time [ns] of each robot's newest command."""
        self.sim_t = 0.0
        self.stats: dict[str, Stats] = {}
        self.end: End | None = None
        self._closed = False
        self._viz = None
        self._viz_lock = threading.Lock()  # the builder keeps state across records
        self._sinks: list = []
        if scenario is not None:  # Foxglove views built from the records (orchestrator/view/foxglove.py)
            from orchestrator.view.foxglove import McapVizSink, VizBuilder

            self._viz = VizBuilder(scenario, keys)
            # records the views never use are not decoded (observations only for range rays)
            self._viz_skip = ("/cmd", "/estimate") + (() if scenario.sensors.enabled else ("/obs",))
            self._sinks = [McapVizSink(self._ctx)] + ([live] if live is not None else [])
            self._static = self._viz.static()  # written with the first record, at its time

    def _emit(self, msgs, now: int) -> None:
        """Hand Foxglove messages to every sink (the MCAP one under the writer's lock)."""
        if not msgs:
            return
        with self._lock:
            if self._closed:
                return
            for topic, msg in msgs:
                self._sinks[0].log(topic, msg, now)
        for sink in self._sinks[1:]:
            for topic, msg in msgs:
                sink.log(topic, msg, now)

    def write(self, key: str, data: bytes, log_time_ns: int | None = None, attachment: bytes | None = None) -> None:
        """Record ``data`` published on ``key`` (stamped now, or at ``log_time_ns``);
        ``attachment``: the link's (incarnation, seq, sender) of the record, counted in
        :attr:`accounts`."""
        now = time.time_ns() if log_time_ns is None else int(log_time_ns)
        rel = self.keys.relative(key)
        acct = None
        with self._lock:
            if self._closed:
                return
            if attachment is not None:
                acct = self._count(attachment, rel)
            ch = self._channels.get(key)
            if ch is None:
                ch = self._ctx._create_channel(key, message_encoding=MessageEncoding.MessagePack, schema=None,
                                               metadata=None)
                self._channels[key] = ch
            self.count += 1
            self.count_by_key[key] = self.count_by_key.get(key, 0) + 1
            if rel.endswith("/cmd"):  # robot/<name>/cmd: when each robot last commanded (a restart's rejoin)
                self.last_cmd_ns[rel.split("/")[1]] = now
            ch.log(data, now)  # sequence: the channel's count, from 1
        # light decoding for progress and the closing account (every record when views are built)
        views = self._viz is not None and not rel.endswith(self._viz_skip)
        if views or rel == "sim/truth" or rel.startswith("stats/") or rel == "sim/end":
            try:
                rec = unpack(data)
            except WireError:
                return
            if isinstance(rec, Truth):
                self.sim_t = rec.t
            elif isinstance(rec, Stats):
                self.stats[rec.proc] = rec
                if acct is not None:
                    acct["closed"] = rec.published
            elif isinstance(rec, End):
                self.end = rec
            if views:
                with self._viz_lock:
                    if self._static:
                        self._emit(self._static, now)
                        self._static = []
                    self._emit(self._viz.feed(key, rec), now)

    def _count(self, attachment: bytes, rel: str) -> dict | None:
        """One record into its sender's account (under the lock): what arrived, and the
        sequence numbers that never did (gaps; one that arrives late closes its gap)."""
        got = read_seq_attachment(attachment)
        if got is None:
            return None
        inc, seq, sender = got
        acct = self.accounts.get((sender, inc))
        if acct is None:
            acct = self.accounts[(sender, inc)] = {"sender": sender, "incarnation": f"{inc:012x}", "received": 0,
                                                   "first": seq, "last": seq - 1, "missing": 0, "closed": None,
                                                   "first_ns": time.time_ns()}
        acct["received"] += 1
        if seq > acct["last"]:
            acct["missing"] += seq - acct["last"] - 1
            acct["last"] = seq
        elif acct["missing"] > 0:  # late, out of order: its gap was counted
            acct["missing"] -= 1
        acct["last_ns"] = time.time_ns()
        return acct

    def account_metadata(self) -> dict[str, str]:
        """The accounts as the log's ``accounts`` metadata: one JSON object per process
        incarnation, keyed ``sender#incarnation`` (docs/reference/faults.md, "Accounts that survive a kill")."""
        with self._lock:
            return {f"{a['sender'] or '?'}#{a['incarnation']}": json.dumps(a) for a in self.accounts.values()}

    def add_process_logs(self, log_dir: pathlib.Path) -> int:
        """Every line of the processes' logs (``log_dir/*.log``) as ``foxglove.Log`` on
        ``/viz/log``; returns the number of lines."""
        if self._viz is None or not pathlib.Path(log_dir).is_dir():
            return 0
        from orchestrator.view.foxglove import process_log_messages

        n = 0
        for t, msg in process_log_messages(log_dir, time.time_ns()):
            self._emit([("/viz/log", msg)], t)
            n += 1
        return n

    def finish(self, extra_metadata: dict[str, dict[str, str]] | None = None) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            extra_metadata = dict(extra_metadata or {})
            if self.accounts:
                extra_metadata.setdefault("accounts", {f"{a['sender'] or '?'}#{a['incarnation']}": json.dumps(a)
                                                       for a in self.accounts.values()})
            for name, data in extra_metadata.items():
                self._mcap.write_metadata(name, {k: str(v) for k, v in data.items()})
            for ch in self._channels.values():
                ch.close()
            self._mcap.close()


def write_records(path: pathlib.Path, records, scenario, run_id: str, origin_ns: int | None = None) -> pathlib.Path:
    """Write the records of an in-process run (``orchestrator.run.inprocess``) as a run log,
    Foxglove views included, stamped ``origin_ns`` (default: now) plus their sim time."""
    keys = Keys(run_id)
    raw = dict(scenario.raw)
    raw["_source"] = scenario.source
    metadata = {"scenario": {"json": json.dumps(raw), "id": scenario.id, "source": scenario.source},
                "copath": {"version": software_version(), "run_id": run_id, "clock": "lockstep",
                           "seed": str(scenario.run.seed), "robots": ",".join(scenario.robot_names), "inprocess": "true"},
                "faults": fault_metadata(scenario)}
    origin = time.time_ns() if origin_ns is None else origin_ns
    rec = Recorder(pathlib.Path(path), keys, metadata, scenario)
    for t, key, r in records:
        rec.write(key, r.pack(), log_time_ns=origin + t)
    rec.finish({"outcome": {"ok": "True", "reason": "in-process run"}})
    return pathlib.Path(path)


class LogError(ValueError):
    """A file that is not a readable copath run log (empty, not MCAP, foreign)."""


@dataclass(frozen=True)
class LogCheck:
    """What :func:`check_log` found out about a file."""

    path: pathlib.Path
    cut_short: bool
    """The file ends before the MCAP footer (a recorder killed mid-run): it is read up to
    its last complete record (chunk)."""


def check_log(path: str | pathlib.Path) -> LogCheck:
    """Check that ``path`` is an MCAP file, and whether it was closed properly.

    Raises FileNotFoundError (no such file) or :class:`LogError` (empty, not an MCAP
    file), each with a one-line message naming the file."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"run log {str(path)!r} does not exist")
    size = path.stat().st_size
    if size == 0:
        raise LogError(f"{path}: the file is empty (0 bytes), not a run log")
    with path.open("rb") as fh:
        head = fh.read(len(MAGIC))
        if head != MAGIC:
            raise LogError(f"{path}: not an MCAP file (it starts with {head[:8]!r}, "
                           f"an MCAP file with {MAGIC!r})")
        fh.seek(max(0, size - len(MAGIC)))
        tail = fh.read(len(MAGIC))
    return LogCheck(path, cut_short=size < 2 * len(MAGIC) + 20 or tail != MAGIC)


def _stream_records(path: pathlib.Path):
    """Records of a file read front to back, up to the last complete one (chunks are
    read whole, so a cut inside a chunk loses that chunk only)."""
    with path.open("rb") as fh:
        reader = StreamReader(fh, record_size_limit=path.stat().st_size)
        try:
            yield from reader.records
        except Exception:  # the cut: a partial record (any of mcap's exceptions)
            return


def read_metadata(path: str | pathlib.Path) -> dict[str, dict[str, str]]:
    """The log's metadata by name (a later record of a name updates the earlier one)."""
    chk = check_log(path)
    out: dict[str, dict[str, str]] = {}
    if chk.cut_short:
        for rec in _stream_records(chk.path):
            if isinstance(rec, Metadata):
                out.setdefault(rec.name, {}).update(rec.metadata)
        return out
    with chk.path.open("rb") as fh:
        for m in make_reader(fh).iter_metadata():
            out.setdefault(m.name, {}).update(dict(m.metadata))
    return out


def require_copath(path: str | pathlib.Path, metadata: dict[str, dict[str, str]]) -> None:
    """Raise :class:`LogError` for an MCAP file that no copath run wrote."""
    if "copath" not in metadata or "scenario" not in metadata:
        if check_log(path).cut_short:
            raise LogError(f"{path}: cut short (it ends before its footer) before any copath run metadata; "
                           "nothing to read")
        raise LogError(f"{path}: an MCAP file, but not a copath run log (no copath run metadata)")


@dataclass
class RunLog:
    """A run log read back: decoded records plus metadata."""

    records: list[tuple[int, str, Any]]
    metadata: dict[str, dict[str, str]]
    rejected: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    cut_short: bool = False
    """The file ended before its footer (recorder killed); records up to the last complete chunk."""

    @property
    def run_id(self) -> str:
        return self.metadata.get("copath", {}).get("run_id", "")

    @property
    def scenario_raw(self) -> dict:
        return json.loads(self.metadata.get("scenario", {}).get("json", "{}"))


def iter_raw(path: str | pathlib.Path) -> Iterator[tuple[int, str, bytes]]:
    """(log_time_ns, key, bytes) of every run message (msgpack) in log order; the derived
    Foxglove channels are left out. A log cut short is read up to its last complete
    chunk. Raises FileNotFoundError or :class:`LogError` for a file that is not MCAP."""
    chk = check_log(path)
    if chk.cut_short:
        channels: dict[int, Any] = {}
        got = []
        for rec in _stream_records(chk.path):
            if type(rec).__name__ == "Channel":
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is not None and ch.message_encoding == MessageEncoding.MessagePack:
                    got.append((rec.log_time, ch.topic, rec.data))
        got.sort(key=lambda m: m[0])  # stable: equal times keep their order in the file
        yield from got
        return
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for _schema, channel, message in reader.iter_messages(log_time_order=True):
            if channel.message_encoding == MessageEncoding.MessagePack:
                yield message.log_time, channel.topic, message.data


def read_log(path: str | pathlib.Path) -> RunLog:
    """Read and decode a run log (records that fail validation are counted, not raised)."""
    chk = check_log(path)
    metadata = read_metadata(path)
    records = []
    rejected = 0
    counts: dict[str, int] = {}
    for t, key, data in iter_raw(path):
        counts[key] = counts.get(key, 0) + 1
        try:
            records.append((t, key, unpack(data)))
        except WireError:
            rejected += 1
    if chk.cut_short and "outcome" not in metadata:
        metadata["outcome"] = {"ok": "False", "reason": "the log was cut short (its recorder stopped before "
                                                        "closing it); read up to its last complete chunk"}
    return RunLog(records, metadata, rejected, counts, chk.cut_short)
