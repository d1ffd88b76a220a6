"""MCAP run logs read back: the reader.

A run log (``run.mcap``, written by ``orchestrator/log/writer.py``'s recorder) holds every
message under the run prefix unchanged (msgpack encoding, schema id 0, one channel per
key), with the effective scenario and the software version as metadata; derived channels
(the Foxglove views) sit beside them and are left out here. A log cut short (its recorder
killed) is read up to its last complete chunk.
"""

from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass, field
from typing import Any, Iterator

from mcap.reader import make_reader
from mcap.records import Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.well_known import MessageEncoding

from copath.wire.messages import WireError, unpack

__all__ = ["RunLog", "read_log", "iter_raw", "LogError", "check_log", "LogCheck", "read_metadata", "require_copath"]

MAGIC = b"\x89MCAP0\r\n"
"""The 8 bytes an MCAP file starts and ends with."""


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
