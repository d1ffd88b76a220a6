"""Writing a run log: the recorder.

Every message under the run prefix lands in ``run.mcap`` unchanged (msgpack encoding,
schema id 0, one channel per key, zstd chunks), stamped with its receive time. The
effective scenario (JSON) and the software version are MCAP metadata, so a run is
explainable from its log alone. The log is read back by ``orchestrator/log/mcap.py``.

The recorder writes records and knows nothing of what is derived from them. Whoever wants
derived channels in the same file (the Foxglove views of ``orchestrator/view/foxglove.py``)
adds a :class:`RecordTap`: it is handed each decoded record and writes its own channels on
the log's context through :meth:`Recorder.derived`.
"""

from __future__ import annotations

import contextlib
import json
import pathlib
import threading
import time
from typing import Any, Callable, Iterable, Iterator, Protocol

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.well_known import MessageEncoding

from copath.wire.keys import Keys
from copath.wire.messages import End, Stats, Truth, WireError, unpack
from copath.wire.session import read_seq_attachment

from orchestrator.version import software_version

__all__ = ["Recorder", "RecordTap", "write_records", "fault_metadata"]


class RecordTap(Protocol):
    """Something fed every record the recorder writes, decoded (e.g. the Foxglove views)."""

    skip: tuple[str, ...]
    """Key endings (relative to the run) it never reads: not decoded for it."""

    def feed(self, key: str, rec: Any, log_time_ns: int) -> None:
        """``rec``, published on ``key``, was written at ``log_time_ns``."""


def fault_metadata(scenario) -> dict[str, str]:
    """The run's injected faults as MCAP metadata ``faults`` (JSON per section): the
    robot-to-robot network faults and the sensor noise, so a log says what was injected
    (each drop and partition window is also an event on the timeline; docs/reference/faults.md)."""
    import dataclasses  # noqa: PLC0415

    out = {"network": json.dumps(dataclasses.asdict(scenario.network))}
    if getattr(scenario, "noise", None) is not None:
        out["noise"] = json.dumps(dataclasses.asdict(scenario.noise))
    return out


class Recorder:
    """Writes every (key, bytes) it is given to an MCAP file; thread-safe.

    The file is written by ``foxglove-sdk``'s MCAP writer (Rust): about 2 us per message
    against 9 us for the pure-Python ``mcap`` writer, which held the recorder to 80 k
    messages/s (docs/journal/performance.md, goals of the issue, measured (P9)). Each key is a channel with message
    encoding ``msgpack`` and schema id 0 (self-describing), as the MCAP spec's well-known
    encodings have it; the SDK's public ``Channel`` asks for a schema for any encoding
    but JSON, so the schemaless channel is made by the context the public class uses."""

    def __init__(self, path: pathlib.Path, keys: Keys, metadata: dict[str, dict[str, str]]) -> None:
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
        self.first_cmd_ns: dict[str, int] = {}
        """Receive time [ns] of each robot's first command since :meth:`expect_commands`
        (0 while none came): when a restarted robot commanded again."""
        self._old_incarnations: dict[str, frozenset[int]] = {}
        """Per robot expected back: the incarnations heard before :meth:`expect_commands`. A
        command still in flight from the killed process is not the new one's first."""
        self.accounts: dict[tuple[str, int], dict] = {}
        """Per (sender, incarnation): records received, first and last sequence number, the
        numbers missing (gaps), and the closing account's ``published`` when one came."""
        self.sim_t = 0.0
        self.stats: dict[str, Stats] = {}
        self.end: End | None = None
        self._closed = False
        self._taps: list[RecordTap] = []

    def expect_commands(self, robot: str) -> None:
        """Note the receive time of ``robot``'s next command in :attr:`first_cmd_ns` (a
        restart: the supervisor measures its rejoin from it, not from whenever it looks)."""
        with self._lock:
            self.first_cmd_ns[robot] = 0
            self._old_incarnations[robot] = frozenset(inc for (s, inc) in self.accounts if s == robot)

    def add_tap(self, tap: RecordTap) -> None:
        """Feed ``tap`` every record written from now on (before the first record: all of them)."""
        self._taps.append(tap)

    @contextlib.contextmanager
    def derived(self) -> Iterator[foxglove.Context | None]:
        """Under the writer's lock: the log's ``foxglove.Context``, on whose channels a tap
        writes derived messages into the same file, or None once the log is closed."""
        with self._lock:
            yield None if self._closed else self._ctx

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
            if self.first_cmd_ns and rel.endswith("/cmd"):  # robot/<name>/cmd: a restart's rejoin
                robot = rel.split("/")[1]
                if self.first_cmd_ns.get(robot) == 0 and not self._from_old_process(robot, attachment):
                    self.first_cmd_ns[robot] = now
            ch.log(data, now)  # sequence: the channel's count, from 1
        # light decoding for progress and the closing account (and for the taps that read the record)
        taps = [t for t in self._taps if not rel.endswith(t.skip)]
        if taps or rel == "sim/truth" or rel.startswith("stats/") or rel == "sim/end":
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
            for tap in taps:
                tap.feed(key, rec, now)

    def _from_old_process(self, robot: str, attachment: bytes | None) -> bool:
        """Whether a command of ``robot`` expected back came from an incarnation heard before
        the restart (a record of the killed process still in flight), by its attachment."""
        got = read_seq_attachment(attachment) if attachment is not None else None
        return got is not None and got[0] in self._old_incarnations.get(robot, ())

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


def write_records(path: pathlib.Path, records, scenario, run_id: str, origin_ns: int | None = None,
                  taps: Iterable[Callable[[Recorder], Any]] = ()) -> pathlib.Path:
    """Write the records of an in-process run (``orchestrator.run.inprocess``) as a run log,
    stamped ``origin_ns`` (default: now) plus their sim time. Each of ``taps`` is called
    with the recorder before the first record, to add what it derives (e.g.
    ``orchestrator.view.foxglove.views_tap(scenario)``: the Foxglove views)."""
    keys = Keys(run_id)
    raw = dict(scenario.raw)
    raw["_source"] = scenario.source
    metadata = {"scenario": {"json": json.dumps(raw), "id": scenario.id, "source": scenario.source},
                "copath": {"version": software_version(), "run_id": run_id, "clock": "lockstep",
                           "seed": str(scenario.run.seed), "robots": ",".join(scenario.robot_names), "inprocess": "true"},
                "faults": fault_metadata(scenario)}
    origin = time.time_ns() if origin_ns is None else origin_ns
    rec = Recorder(pathlib.Path(path), keys, metadata)
    for attach in taps:
        attach(rec)
    for t, key, r in records:
        rec.write(key, r.pack(), log_time_ns=origin + t)
    rec.finish({"outcome": {"ok": "True", "reason": "in-process run"}})
    return pathlib.Path(path)
