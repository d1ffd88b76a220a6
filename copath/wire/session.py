"""The one Zenoh session factory and link of copath (nothing else opens a session).

Isolation (docs/journal/measurements.md, isolation and multicast scouting (W1-W3)): multicast scouting is always off; by default
sessions listen and connect on loopback only, on a port chosen per run, so two runs on
one machine never hear each other. The orchestrator hosts the run's router itself (a Python
session in ``router`` mode: no zenohd to install or start); simulator and agents
connect to it as clients. ``--connect``/``--listen`` endpoints allow multi-host runs.

Pitfalls handled here (docs/journal/measurements.md, congestion control and wire pitfalls (W5-W6)): a subscriber still declared at
interpreter exit hangs the process, so :class:`ZenohLink` undeclares everything in
``close()`` (use it as a context manager); callbacks catch their own exceptions and
count rejects; records that must not be lost are published with congestion control BLOCK.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import struct
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import zenoh

from .acl import AccessPolicy
from .link import key_matches
from .messages import WireError, unpack
from .trust import RejectLog, check_origin

logger = logging.getLogger(__name__)

__all__ = ["SessionConfig", "open_session", "free_port", "ZenohLink", "loopback_endpoint", "seq_attachment",
           "read_seq_attachment"]

MODES = ("client", "peer", "router")


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def loopback_endpoint(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


@dataclass(frozen=True)
class SessionConfig:
    """How a process joins a run's Zenoh network."""

    mode: str = "client"
    """``client`` (default: through the run's router), ``peer`` or ``router``."""
    connect: tuple[str, ...] = ()
    """Endpoints to connect to, e.g. ``tcp/127.0.0.1:7447``."""
    listen: tuple[str, ...] = ()
    """Endpoints to listen on (routers; loopback unless a deployment names others)."""
    lease_ms: int | None = 1000
    """Transport lease: a frozen process loses its liveliness within about this time."""
    extra: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    """Further ``(key, json5 value)`` entries of the Zenoh config (``--cfg KEY:VALUE``)."""
    config_file: str | None = None
    """A Zenoh JSON5 config file to start from (``--zenoh-config``)."""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"zenoh mode = {self.mode!r} is not allowed; allowed: {', '.join(MODES)}")
        for e in self.connect + self.listen:
            if "/" not in e:
                raise ValueError(f"endpoint = {e!r} is not allowed; expected PROTO/ADDR:PORT, e.g. tcp/127.0.0.1:7447")
        if self.mode == "client" and not self.connect:
            raise ValueError("a client session needs at least one connect endpoint (--connect)")

    @property
    def authenticated(self) -> bool:
        """The session logs in with a user name (secure mode, docs/reference/security.md)."""
        if any(k.startswith("transport/auth") for k, _ in self.extra):
            return True
        if self.config_file:
            try:
                text = open(self.config_file, encoding="utf-8").read()
            except OSError:
                return False
            return '"usrpwd"' in text and '"user"' in text
        return False

    def to_zenoh(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/delay", "0")
        conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.mode == "client":
            # keep retrying the router instead of failing at once (docs/journal/measurements.md, clients started before their router (W3))
            conf.insert_json5("connect/timeout_ms", "-1")
            # after a transport reset (a lease that lapsed on a starved machine) reconnect within
            # 0.1-1 s, well inside run.liveliness_grace_s (zenoh's default backs off from 1 s to 4 s)
            conf.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 1000, '
                                               '"period_increase_factor": 2}')
        if self.lease_ms:
            conf.insert_json5("transport/link/tx/lease", str(int(self.lease_ms)))
        for k, v in self.extra:
            conf.insert_json5(k, v)
        return conf


SLOW_CONNECT_S = 10.0
"""A client still without a session after this long says why it may be waiting [s]."""


def open_session(conf: SessionConfig) -> zenoh.Session:
    """Open a session; a client keeps retrying its router until it is admitted.

    A router that refuses the session (a secure run and no or wrong credentials) looks,
    from here, like one that is not up yet: Zenoh retries either way without a word. So a
    client that waits longer than :data:`SLOW_CONNECT_S` logs what to check."""
    if conf.mode != "client":
        return zenoh.open(conf.to_zenoh())
    hint = ("the run's credentials file is given (--zenoh-config) but the router has not admitted it: "
            "is it this run's file?" if conf.authenticated else
            "a secure run (the default) refuses sessions without the run's credentials: pass "
            "--zenoh-config RUN_DIR/secrets/<robot>.json5, as printed by copath run --external")
    timer = threading.Timer(SLOW_CONNECT_S, logger.warning, args=(
        "no session with the router at %s after %.0f s; still trying. Is the router up and reachable? %s",
        ", ".join(conf.connect), SLOW_CONNECT_S, hint))
    timer.daemon = True
    timer.start()
    try:
        return zenoh.open(conf.to_zenoh())
    finally:
        timer.cancel()


Callback = Callable[[str, Any], None]

_SEQ = struct.Struct("<QQ")


def seq_attachment(incarnation: int, seq: int, sender: str) -> bytes:
    """The link-layer account of one record: (incarnation, sequence number from 1, sender).

    Every record a :class:`ZenohLink` publishes carries it as its Zenoh attachment, outside
    the record's schema, so the recorder counts what it received from each process and
    finds the gaps (records lost on the way), and a process killed before its closing
    account is still accounted for up to its last record (docs/reference/faults.md, "Accounts that
    survive a kill")."""
    return _SEQ.pack(incarnation, seq) + sender.encode()


def read_seq_attachment(data: bytes | None) -> tuple[int, int, str] | None:
    """(incarnation, seq, sender) of :func:`seq_attachment`, or None (none, or not ours)."""
    if not data or len(data) < _SEQ.size:
        return None
    inc, seq = _SEQ.unpack_from(data)
    try:
        return inc, seq, data[_SEQ.size:].decode()
    except UnicodeDecodeError:
        return None


class ZenohLink:
    """Publishes and receives copath records on one session; counts what it published.

    ``publish`` keeps one declared publisher per key (congestion control BLOCK, so
    nothing is dropped by the publisher). Subscribers decode and validate records in
    the Zenoh callback thread and hand them to ``callback(key, record)``; a record that
    fails validation, or a callback that raises, is counted in ``rejects``.
    """

    synchronous = False
    """Records arrive on Zenoh's threads, after ``publish`` returns (:class:`copath.wire.link.Link`)."""

    def __init__(self, session: zenoh.Session, declare_publishers: bool = True) -> None:
        self.session = session
        self.declare_publishers = declare_publishers
        """False: every record goes out with ``session.put`` (under access control, eclipse-zenoh
        1.10 lets only the first put of a declared publisher through; docs/reference/security.md)."""
        self.published = 0
        self.sender = ""
        """Who publishes through this link (``sim``, a robot's name): carried in every
        record's attachment with :attr:`incarnation` and a sequence number (:func:`seq_attachment`)."""
        self.incarnation = int.from_bytes(os.urandom(6), "little")
        """This process's session, told apart from an earlier one of the same sender (a restart)."""
        self.reject_log = RejectLog()
        self._pubs: dict[str, Any] = {}
        self._keyexprs: dict[str, zenoh.KeyExpr] = {}
        self._decls: list[Any] = []
        self._lock = threading.Lock()
        self._closed = False
        self._droppable: tuple[str, ...] = ()
        self.local_delivery = True
        """False: what this link publishes does not reach this session's own subscribers
        (``Locality.REMOTE``; the router and the recorder still get it). An agent listens on
        ``peer/*/all`` and would decode its own broadcast, inside the put, only to drop it
        (docs/journal/performance.md, the wire, msgspec (P18)). Set before the first publish."""
        self._policy: AccessPolicy | None = None
        self._user: str | None = None

    def guard(self, policy: AccessPolicy, user: str) -> None:
        """Check every declaration and publication of ``user`` against ``policy`` (a
        session that logs in to a secure router): the router refuses what the grants do not
        cover without a word, so a node stepping outside them fails here at once, naming
        the key (:class:`copath.wire.acl.AccessDenied`), instead of waiting for messages
        that never come."""
        self._policy, self._user = policy, user

    def _check(self, action: str, key: str) -> None:
        if self._policy is not None:
            self._policy.check(self._user, action, key)

    def drop_when_congested(self, *key_exprs: str) -> None:
        """Publish records on keys matching ``key_exprs`` with congestion control DROP.

        For streams where only the newest value matters (realtime observations and
        neighbour broadcasts): a receiver that falls behind (a starved process) then loses
        old samples instead of making the router wait for it. With BLOCK the router's
        forwarding waits for that receiver's queue, stops reading the other links (their
        1 s lease lapses) and after 5 s closes the transport (docs/journal/performance.md, realtime at 128 robots (P10)).
        The local recorder still gets every record. Call before the first publish on a key."""
        self._droppable += tuple(key_exprs)

    def _congestion(self, key: str) -> "zenoh.CongestionControl":
        if any(key_matches(key, e) for e in self._droppable):
            return zenoh.CongestionControl.DROP
        return zenoh.CongestionControl.BLOCK

    def _destination(self) -> "zenoh.Locality | None":
        return None if self.local_delivery else zenoh.Locality.REMOTE

    @property
    def rejects(self) -> int:
        """Messages rejected so far (schema, origin, or a callback that raised)."""
        return self.reject_log.total

    @classmethod
    def open(cls, conf: SessionConfig) -> "ZenohLink":
        return cls(open_session(conf), declare_publishers=not conf.authenticated)

    def __enter__(self) -> "ZenohLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def publish(self, key: str, record: Any) -> None:
        self.publish_bytes(key, record.pack())

    def publish_bytes(self, key: str, data: bytes) -> None:
        self._check("publish", key)
        if not self.declare_publishers:
            with self._lock:
                ke = self._keyexprs.get(key)
                if ke is None:
                    ke = self._keyexprs[key] = zenoh.KeyExpr(key)  # parsed once
                self.published += 1
                self.session.put(ke, data, congestion_control=self._congestion(key),
                                 attachment=seq_attachment(self.incarnation, self.published, self.sender),
                                 allowed_destination=self._destination())
            return
        with self._lock:
            pub = self._pubs.get(key)
            if pub is None:
                pub = self.session.declare_publisher(key, congestion_control=self._congestion(key),
                                                     allowed_destination=self._destination())
                self._pubs[key] = pub
            self.published += 1
            pub.put(data, attachment=seq_attachment(self.incarnation, self.published, self.sender))

    def subscribe(self, key_expr: str, callback: Callback, on_reject: Callable[[str, str], None] | None = None) -> None:
        """Decode every sample on key_expr and call ``callback(key, record)``; a sample that
        fails validation is counted and handed to ``on_reject(key, error)`` instead."""
        self._check("subscribe", key_expr)

        def handler(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            try:
                rec = unpack(sample.payload.to_bytes())
                check_origin(key, rec)
            except WireError as exc:
                self.reject_log.add(key, str(exc))
                if self.reject_log.total <= 20 or self.reject_log.total % 1000 == 0:  # a flood stays readable
                    logger.warning("rejected message on %s: %s (%d so far)", key, exc, self.reject_log.total)
                if on_reject is not None:
                    try:
                        on_reject(key, str(exc))
                    except Exception:
                        logger.exception("reject callback failed on %s", key)
                return
            try:
                callback(key, rec)
            except WireError as exc:  # a receiver-side check in the callback
                self.reject_log.add(key, str(exc))
                if self.reject_log.total <= 20 or self.reject_log.total % 1000 == 0:
                    logger.warning("rejected message on %s: %s (%d so far)", key, exc, self.reject_log.total)
            except Exception as exc:  # never let a callback die silently in a loop
                self.reject_log.add(key, f"callback failed: {exc!r}")
                logger.exception("subscriber callback failed on %s", key)

        self._decls.append(self.session.declare_subscriber(key_expr, handler))

    def subscribe_raw(self, key_expr: str, callback: Callable[..., None], attachment: bool = False) -> None:
        """Call ``callback(key, payload_bytes)`` for every sample (the recorder); with
        ``attachment``, ``callback(key, payload_bytes, attachment=bytes or None)``."""
        self._check("subscribe", key_expr)

        def handler(sample: zenoh.Sample) -> None:
            try:
                if attachment:
                    att = sample.attachment
                    callback(str(sample.key_expr), sample.payload.to_bytes(),
                             attachment=None if att is None else att.to_bytes())
                    return
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception as exc:
                self.reject_log.add(str(sample.key_expr), f"callback failed: {exc!r}")
                logger.exception("raw subscriber callback failed on %s", sample.key_expr)

        self._decls.append(self.session.declare_subscriber(key_expr, handler))

    def declare_token(self, key: str) -> None:
        """Liveliness token: disappears within milliseconds when the process dies."""
        self._check("token", key)
        self._decls.append(self.session.liveliness().declare_token(key))

    def watch_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        """Call ``callback(key, alive)`` when a token appears (True) or disappears (False)."""
        self._check("watch", key_expr)

        def handler(sample: zenoh.Sample) -> None:
            try:
                callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            except Exception:
                logger.exception("liveliness callback failed on %s", sample.key_expr)

        self._decls.append(self.session.liveliness().declare_subscriber(key_expr, history=True, handler=handler))

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for d in reversed(self._decls):
            try:
                d.undeclare()
            except Exception:  # already gone with a dead router
                pass
        for p in self._pubs.values():
            try:
                p.undeclare()
            except Exception:
                pass
        try:
            self.session.close()
        except Exception:
            pass
