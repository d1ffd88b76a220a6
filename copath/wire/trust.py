"""Receive-side checks beyond the schema: does a record belong on the key it came on?

A record can pass its schema (:mod:`copath.wire.messages`) and still be a forgery or a
mistake: a peer envelope whose sender is not the robot named in its key, an observation
published on a command key, an ``End`` on a robot's key. Every subscriber of a run
(:class:`copath.wire.session.ZenohLink`) applies :func:`check_origin` after decoding, and
every robot applies :class:`StampWindow` to peer stamps before a message enters its fault
queue, so no single message can block a queue, crash a controller or end a run.

Without secure mode nothing on the bus authenticates a publisher: a forgery that is
well-formed and carries the right sender name still passes these checks. Secure mode
(docs/reference/security.md) closes that gap with per-run credentials and access control, so only
the simulator can publish under ``sim/`` and observations, and each robot only under its
own keys. Both layers are described in docs/reference/faults.md.

:class:`RejectLog` counts what a process rejected, by reason, and hands out one
``messages_rejected`` event per interval (rate-limited: a flood of garbage becomes one
event per second, not one per message).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

from .messages import (Command, End, Estimate, Event, Obs, PeerEnvelope, Start, Stats, Telemetry, Truth,
                       WireError)

__all__ = ["check_origin", "StampWindow", "RejectLog", "relative_key"]


def relative_key(key: str) -> list[str]:
    """Chunks of a run key after ``copath/<run_id>/`` (``["robot", "r1", "obs"]``)."""
    parts = str(key).split("/")
    return parts[2:] if len(parts) > 2 else []


_ROBOT_RECORDS = {"obs": Obs, "cmd": Command, "telemetry": Telemetry, "estimate": Estimate}
_SIM_RECORDS = {"start": Start, "end": End, "truth": Truth}


def check_origin(key: str, rec) -> None:
    """Raise :class:`WireError` unless ``rec`` is the record type its key carries and
    the names inside it match the names in the key.

    ============================  ===============================================
    key (after the run prefix)    allowed record
    ============================  ===============================================
    ``robot/<r>/obs|cmd|...``     Obs, Command, Telemetry, Estimate respectively
    ``peer/<s>/all``, ``to/<r>``  PeerEnvelope with ``sender == s``
    ``sim/start|end|truth``       Start, End, Truth
    ``<proc>/event``              Event with ``source == proc``
    ``stats/<proc>``              Stats with ``proc == proc``
    ============================  ===============================================
    """
    rule = _RULES.get(key)
    if rule is None:
        rule = _rule(key)
        if len(_RULES) < _MAX_RULES:  # keys repeat; a flood of made-up keys must not grow it
            _RULES[key] = rule
    rel, want, attr, name = rule
    if want is PeerEnvelope and isinstance(rec, PeerEnvelope) and rec.sender != name:
        raise WireError(f"peer envelope from sender {rec.sender!r} on {name!r}'s key")
    if attr is not None and isinstance(rec, want) and getattr(rec, attr) != name:
        raise WireError(_MISMATCH[attr].format(getattr(rec, attr), name))
    if want is None:
        raise WireError(f"key {'/'.join(rel) or key!r} carries no copath record")
    if not isinstance(rec, want):
        raise WireError(f"a {rec.TYPE!r} record on {'/'.join(rel)} (expected {want.TYPE!r})")


_MISMATCH = {"source": "event from source {!r} on {!r}'s key", "proc": "closing account of {!r} on {!r}'s key"}
_MAX_RULES = 4096
_RULES: dict[str, tuple] = {}
"""What :func:`check_origin` wants on each key it has seen: (chunks, record type, the field
naming the publisher, that name); read from the key once."""


def _rule(key: str) -> tuple:
    rel = relative_key(key)
    want, attr, name = None, None, None
    if len(rel) == 3 and rel[0] == "robot":
        want = _ROBOT_RECORDS.get(rel[2])
    elif len(rel) in (3, 4) and rel[0] == "peer" and (rel[2] == "all" or (rel[2] == "to" and len(rel) == 4)):
        want, name = PeerEnvelope, rel[1]
    elif len(rel) == 2 and rel[0] == "sim" and rel[1] in _SIM_RECORDS:
        want = _SIM_RECORDS[rel[1]]
    elif len(rel) == 2 and rel[1] == "event":
        want, attr, name = Event, "source", rel[0]
    elif len(rel) == 2 and rel[0] == "stats":
        want, attr, name = Stats, "proc", rel[1]
    return rel, want, attr, name


@dataclass(frozen=True)
class StampWindow:
    """Plausible sender stamps of a peer message at receiver time ``now``.

    ``future_s``: how far ahead of the receiver's clock a stamp may be (lockstep: one tick;
    realtime: the clocks are synchronised once at start, so a step period plus jitter);
    ``past_s``: how old it may be (the fault layer's delay and jitter plus a margin).
    Anything outside the window is a forgery or a broken clock and is rejected before it
    enters the fault queue, where a stamp far ahead would never be released.
    """

    future_s: float = 2.0
    past_s: float = 30.0

    @classmethod
    def for_run(cls, dt: float, delay_ms: float = 0.0, jitter_ms: float = 0.0) -> "StampWindow":
        return cls(future_s=max(2.0, 10.0 * dt), past_s=30.0 + 2.0 * (delay_ms + jitter_ms) / 1000.0)

    def check(self, stamp: float, now: float) -> None:
        if not math.isfinite(stamp):
            raise WireError(f"stamp = {stamp!r} is not a finite number")
        if stamp > now + self.future_s:
            raise WireError(f"stamp = {stamp:.3f} s is {stamp - now:.3f} s ahead of the receiver's clock "
                            f"(at most {self.future_s:.3f} s allowed)")
        if stamp < now - self.past_s:
            raise WireError(f"stamp = {stamp:.3f} s is {now - stamp:.3f} s old "
                            f"(at most {self.past_s:.3f} s allowed)")


class RejectLog:
    """Counts rejected messages by reason; thread-safe (Zenoh callbacks count into it)."""

    def __init__(self, min_interval_s: float = 1.0) -> None:
        self.total = 0
        self.by_reason: dict[str, int] = {}
        self.last: tuple[str, str] | None = None
        self._lock = threading.Lock()
        self._reported = 0
        self._reported_at: float | None = None
        self._min_interval_s = float(min_interval_s)

    @staticmethod
    def reason_of(message: str) -> str:
        """A short class of a reject message (its first words), for the per-reason counts."""
        head = message.split(":", 1)[0] if ":" in message[:40] else message
        words = head.replace("=", " ").split()
        return " ".join(words[:3])[:48] or "unknown"

    def add(self, key: str, message: str) -> None:
        with self._lock:
            self.total += 1
            r = self.reason_of(message)
            self.by_reason[r] = self.by_reason.get(r, 0) + 1
            self.last = (str(key), message[:200])

    def event(self, source: str, t: float, wall: float) -> Event | None:
        """A ``messages_rejected`` event when something new was rejected and ``min_interval_s``
        of wall time ``wall`` has passed since the previous one; else None."""
        if self.total == self._reported:  # nothing new (asked once per step: no lock for that)
            return None
        with self._lock:
            if self.total == self._reported:
                return None
            if self._reported_at is not None and wall - self._reported_at < self._min_interval_s:
                return None
            new = self.total - self._reported
            self._reported, self._reported_at = self.total, wall
            key, msg = self.last or ("", "")
            return Event(float(t), source, "messages_rejected",
                         {"count": new, "total": self.total, "by_reason": dict(self.by_reason),
                          "last_key": key, "last_error": msg})

    def flush(self, source: str, t: float) -> Event | None:
        """The closing event: whatever was rejected since the last one (no rate limit)."""
        with self._lock:
            self._reported_at = None
        return self.event(source, t, 0.0)
