"""The transport the nodes talk through: a small :class:`Link` interface, two implementations.

The robot and simulator nodes (``agent/node.py``, ``sim/node.py``) only publish records,
subscribe to key expressions, declare liveliness tokens and watch them. Behind that:

- :class:`copath.wire.session.ZenohLink`: one Zenoh session (separate processes);
- :class:`MemoryLink` on a :class:`MemoryBus`: every node of a run in one process. A
  publish delivers the record object to every matching subscriber *synchronously*, in the
  publisher's thread, without packing it (``synchronous = True``), so the in-process loop
  (``orchestrator/run/inprocess.py``) runs the very same node code, lockstep protocol
  included, with no threads and no copies.

Key expressions follow Zenoh's rules for the two wildcards copath uses: ``*`` is one
chunk, ``**`` is any number of chunks (docs/reference/performance.md, "One lockstep protocol").

Receiver validation is the same on both: a Zenoh subscriber decodes with
:func:`copath.wire.messages.unpack` and checks :func:`copath.wire.trust.check_origin`; a
:class:`MemoryBus` made with ``validate`` runs the same schema checks on the record object
(:func:`validate_record`: the bytes the Zenoh link would publish, decoded as a subscriber decodes them)
and the same origin check, once per published record. The in-process loop validates the
peer envelopes: the records whose content (kind, payload) a user's controller decides,
unchecked by the sender; the others are built by copath's own simulator and runtime in the
same process (the runtime checks a controller's command itself), and a stranger cannot
publish on an in-memory bus (checking them too cost 6 % of an E5.4 run). A
refused record is counted in each subscriber link's ``reject_log`` and handed to the
subscription's ``on_reject(key, error)``, never to its callback (docs/reference/faults.md, "Rejected
messages and the lockstep barrier").
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Callable, Protocol, runtime_checkable

from .messages import WireError, unpack
from .trust import RejectLog, check_origin

if TYPE_CHECKING:
    from .acl import AccessPolicy

logger = logging.getLogger(__name__)

__all__ = ["Link", "MemoryBus", "MemoryLink", "key_matches", "Callback", "RejectCallback", "validate_record"]

Callback = Callable[[str, Any], None]
RejectCallback = Callable[[str, str], None]
"""``on_reject(key, error)``: a record received on ``key`` was refused (the lockstep barrier
counts a refused peer message as delivered-and-dropped, attributed by its key)."""


def validate_record(key: str, rec: Any) -> Any:
    """The receiver validation of a Zenoh subscriber on a record object: the bytes a
    :class:`copath.wire.session.ZenohLink` would publish (``rec.pack()``) decoded as its
    subscriber decodes them (schema: field types, finite numbers, peer payloads), and its
    origin (:func:`copath.wire.trust.check_origin`); raises :class:`WireError`, returns the
    record. A record that cannot be packed is refused by ``from_dict``'s Python checks."""
    pack = getattr(rec, "pack", None)
    if pack is None:
        raise WireError(f"a {type(rec).__name__} is not a copath record")
    try:
        data = pack()  # the bytes a Zenoh link publishes (msgspec: half the time of to_dict and msgpack)
    except Exception:  # a value that cannot be packed (an object): the Python checks decide
        type(rec).from_dict(rec.to_dict())
    else:
        unpack(data)  # msgspec's checks in C; what they refuse, the Python checks refuse with a reason
    check_origin(key, rec)
    return rec


@runtime_checkable
class Link(Protocol):
    """What a node needs from its transport."""

    published: int
    """Records this link published (the closing account's ``published``)."""
    rejects: int
    """Received records refused (schema errors, failing callbacks)."""
    synchronous: bool
    """True when ``publish`` has already run every subscriber's callback when it returns
    (in-memory); False when records arrive on other threads (Zenoh)."""
    reject_log: RejectLog
    """What this link refused, by reason (``rejects`` is its total). A robot's runtime counts
    its own stamp checks into the same log, so each reject is counted once per process."""

    def publish(self, key: str, record: Any) -> None: ...

    def subscribe(self, key_expr: str, callback: Callback, on_reject: RejectCallback | None = None) -> None: ...

    def declare_token(self, key: str) -> None: ...

    def watch_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None: ...

    def drop_when_congested(self, *key_exprs: str) -> None:
        """Publish records on keys matching ``key_exprs`` so that a receiver that falls
        behind loses old ones instead of stalling the others (realtime streams where only
        the newest value matters; docs/journal/performance.md, realtime at 128 robots
        (P10)). Call before the first publish on those keys."""
        ...

    def close(self) -> None: ...


def key_matches(key: str, expr: str) -> bool:
    """True when the concrete ``key`` matches key expression ``expr`` (``*``: one chunk,
    ``**``: zero or more chunks)."""
    return _match(key.split("/"), expr.split("/"))


def _match(k: list[str], e: list[str]) -> bool:
    if not e:
        return not k
    head = e[0]
    if head == "**":
        return any(_match(k[i:], e[1:]) for i in range(len(k) + 1))
    if not k:
        return False
    if head != "*" and head != k[0]:
        return False
    return _match(k[1:], e[1:])


class MemoryBus:
    """The in-process network of one run: subscriptions, tokens and (optionally) the log.

    ``clock()`` gives the log time [s] of a record (the in-process loop passes the
    simulator's time); with ``record=True`` every published record is kept in
    :attr:`records` as ``(log time [ns], key, record)``, like the recorder's MCAP log.
    """

    def __init__(self, clock: Callable[[], float] | None = None, record: bool = True,
                 policy: "AccessPolicy | None" = None, validate: bool | tuple[type, ...] = False) -> None:
        self.clock = clock or (lambda: 0.0)
        self.record = record
        self.validate = validate
        """Validate delivered records as a Zenoh subscriber does (:func:`validate_record`):
        every record (True) or those of the given record types."""
        self.policy = policy
        """Secure mode's access policy (:mod:`copath.wire.acl`), enforced on every link
        opened with a user name: a node stepping outside its grants raises at once."""
        self.records: list[tuple[int, str, Any]] = []
        self._subs: list[tuple[str, Callback, "MemoryLink", RejectCallback | None]] = []
        self._route: dict[str, list[tuple[Callback, "MemoryLink", RejectCallback | None]]] = {}
        self._tokens: set[str] = set()
        self._watchers: list[tuple[str, Callable[[str, bool], None]]] = []

    def link(self, user: str | None = None) -> "MemoryLink":
        """A node's link; ``user`` (``sim`` or a robot name) is checked against the bus's
        policy, like the process of that name behind a secure router."""
        return MemoryLink(self, user if self.policy is not None else None)

    def _subscribe(self, expr: str, callback: Callback, link: "MemoryLink",
                   on_reject: RejectCallback | None = None) -> None:
        self._subs.append((expr, callback, link, on_reject))
        self._route.clear()

    def _unsubscribe(self, link: "MemoryLink") -> None:
        self._subs = [s for s in self._subs if s[2] is not link]
        self._route.clear()

    def _deliver(self, key: str, record: Any) -> None:
        if self.record:
            self.records.append((int(round(self.clock() * 1e9)), key, record))
        route = self._route.get(key)
        if route is None:
            route = self._route[key] = [(cb, ln, rj) for expr, cb, ln, rj in self._subs if key_matches(key, expr)]
        v = self.validate
        if v and route and (v is True or isinstance(record, v)):  # once per record: every receiver refuses alike
            try:
                validate_record(key, record)
            except WireError as exc:
                for _, ln, rj in route:
                    ln.reject_log.add(key, str(exc))
                    if rj is not None:
                        rj(key, str(exc))
                return
        for cb, ln, _ in route:
            try:
                cb(key, record)
            except WireError as exc:  # a receiver-side check in the callback
                ln.reject_log.add(key, str(exc))
            except Exception as exc:  # like the Zenoh link: count, log, keep delivering
                ln.reject_log.add(key, f"callback failed: {exc!r}")
                logger.exception("subscriber callback failed on %s", key)

    def _token(self, key: str, alive: bool) -> None:
        (self._tokens.add if alive else self._tokens.discard)(key)
        for expr, cb in list(self._watchers):
            if key_matches(key, expr):
                cb(key, alive)

    def _watch(self, expr: str, callback: Callable[[str, bool], None]) -> None:
        self._watchers.append((expr, callback))
        for key in sorted(self._tokens):  # history, like Zenoh's liveliness subscriber
            if key_matches(key, expr):
                callback(key, True)


class MemoryLink:
    """One node's :class:`Link` on a :class:`MemoryBus` (records are passed, not packed)."""

    synchronous = True

    def __init__(self, bus: MemoryBus, user: str | None = None) -> None:
        self.bus = bus
        self.user = user
        """Checked against ``bus.policy`` (None: unchecked)."""
        self.published = 0
        self.reject_log = RejectLog()
        """What this node refused (shared with its robot runtime, as a Zenoh link's)."""
        self._tokens: list[str] = []
        self._closed = False

    @property
    def rejects(self) -> int:
        return self.reject_log.total

    def __enter__(self) -> "MemoryLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def publish(self, key: str, record: Any) -> None:
        if self.user is not None:
            self.bus.policy.check(self.user, "publish", key)
        self.published += 1
        self.bus._deliver(key, record)

    def subscribe(self, key_expr: str, callback: Callback, on_reject: RejectCallback | None = None) -> None:
        if self.user is not None:
            self.bus.policy.check(self.user, "subscribe", key_expr)
        self.bus._subscribe(key_expr, callback, self, on_reject)

    def drop_when_congested(self, *key_exprs: str) -> None:
        """Nothing to do: a synchronous publish has delivered before it returns, no queue
        can fill."""

    def declare_token(self, key: str) -> None:
        if self.user is not None:
            self.bus.policy.check(self.user, "token", key)
        self._tokens.append(key)
        self.bus._token(key, True)

    def watch_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        if self.user is not None:
            self.bus.policy.check(self.user, "watch", key_expr)
        self.bus._watch(key_expr, callback)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self.bus._unsubscribe(self)
        for key in self._tokens:
            self.bus._token(key, False)
