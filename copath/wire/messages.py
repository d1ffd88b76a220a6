"""Message schemas of a copath run, packed with msgpack (the one place that defines them).

Every record is a frozen dataclass that packs itself to a msgpack map carrying
``v`` (``WIRE_VERSION``) and ``type`` (its tag) and unpacks with validation: a record of
another version, an unknown tag, a missing field or a field of the wrong type raises
:class:`WireError`, which receivers count as a reject instead of crashing.

Arrays cross the boundary as lists of Python floats (msgpack refuses numpy scalars
other than float64; docs/journal/measurements.md, msgpack at the wire boundary (W7)).

Receivers decode with msgspec: each record class has a typed twin (a ``msgspec.Struct``
built from its ``FIELDS``) that decodes and checks field types and finite numbers in C.
Whatever that fast path refuses is decoded again by the plain msgpack path with the Python
checks, which names the reason; so the records accepted and the errors raised are those of
the Python checks (docs/journal/performance.md, the wire, msgspec (P18)).
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Mapping, NamedTuple, NotRequired, Optional, TypedDict, Union

import msgpack
import msgspec

from .payloads import PAYLOADS

__all__ = [
    "WIRE_VERSION",
    "WireError",
    "Obs",
    "Estimate",
    "Command",
    "Telemetry",
    "Truth",
    "PeerEnvelope",
    "Start",
    "End",
    "Event",
    "Stats",
    "RECORD_TYPES",
    "unpack",
    "unpack_checked",
    "validate_payload",
    "to_plain",
]

WIRE_VERSION = 1


class WireError(ValueError):
    """A received message does not match its schema."""


_PLAIN_TYPES = frozenset({float, int, str, bool, type(None)})
"""Exact types msgpack packs as they are (subclasses such as numpy's float64 take the slow path)."""


def to_plain(x: Any) -> Any:
    """Convert numpy arrays/scalars and tuples into msgpack-friendly Python values.

    Values of the plain types and lists, tuples and dicts of them take a fast path (no
    recursion per element); the result, and so the packed bytes, are the same as the
    general conversion's (docs/journal/performance.md, profile of E5.4 (P12))."""
    t = type(x)
    if t in _PLAIN_TYPES:
        return x
    if t is list or t is tuple:
        return [v if type(v) in _PLAIN_TYPES else to_plain(v) for v in x]
    if t is dict:
        return {(k if type(k) is str else str(k)): (v if type(v) in _PLAIN_TYPES else to_plain(v))
                for k, v in x.items()}
    if hasattr(x, "tolist"):
        return x.tolist()
    if isinstance(x, (list, tuple)):
        return [to_plain(v) for v in x]
    if isinstance(x, dict):
        return {str(k): to_plain(v) for k, v in x.items()}
    return x


def _finite(v: Any) -> bool:
    """A number that is not NaN or infinite (ints always; bools are not numbers)."""
    if isinstance(v, bool):
        return False
    if isinstance(v, int):
        return True
    return isinstance(v, float) and math.isfinite(v)


def _distance(v: Any) -> bool:
    """A finite number, or +inf (a range sensor or clearance that sees nothing)."""
    return _finite(v) or (isinstance(v, float) and v == math.inf)


_CHECKS = {
    "float": _finite,
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "bool": lambda v: isinstance(v, bool),
    "str": lambda v: isinstance(v, str),
    "floats": lambda v: isinstance(v, list) and all(_CHECKS["float"](e) for e in v),
    "ints": lambda v: isinstance(v, list) and all(_CHECKS["int"](e) for e in v),
    "points": lambda v: isinstance(v, list)
    and all(isinstance(e, list) and len(e) == 2 and all(_CHECKS["float"](c) for c in e) for e in v),
    "any": lambda v: True,
    "dict": lambda v: isinstance(v, dict),
    "dict?": lambda v: v is None or isinstance(v, dict),
    "floats?": lambda v: v is None or _CHECKS["floats"](v),
    "float?": lambda v: v is None or _CHECKS["float"](v),
    "strs": lambda v: isinstance(v, list) and all(isinstance(e, str) for e in v),
    "strs?": lambda v: v is None or _CHECKS["strs"](v),
    "bools": lambda v: isinstance(v, list) and all(isinstance(e, bool) for e in v),
    "matrix": lambda v: isinstance(v, list) and all(_CHECKS["floats"](e) for e in v),
    "distances?": lambda v: v is None or (isinstance(v, list) and all(_distance(e) for e in v)),
    "counts": lambda v: isinstance(v, dict) and all(isinstance(k, str) and _CHECKS["int"](n) for k, n in v.items()),
    "counts?": lambda v: v is None or _CHECKS["counts"](v),
    "stamps?": lambda v: v is None or (isinstance(v, dict) and all(isinstance(k, str) and _finite(t) for k, t in v.items())),
}


_KIND_RE = re.compile(r"[a-z][a-z0-9_]{0,63}")
"""A message kind: a lower-case name (the built-in kinds and a user controller's own)."""
_MAX_DEPTH = 8


def _check_plain(value: Any, where: str, depth: int = 0) -> None:
    """Plain msgpack values only (maps with string keys, lists, str, bool, int, finite float)."""
    if depth > _MAX_DEPTH:
        raise WireError(f"{where}: nested deeper than {_MAX_DEPTH} levels")
    if isinstance(value, float):
        if not math.isfinite(value):
            raise WireError(f"{where} = {value!r} is not a finite number")
    elif isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, str):
                raise WireError(f"{where}: map key {k!r} is not a string")
            _check_plain(v, f"{where}.{k}", depth + 1)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _check_plain(v, f"{where}[{i}]", depth + 1)
    elif not (value is None or isinstance(value, (str, bool, int))):
        raise WireError(f"{where}: {type(value).__name__} is not a plain value")


def validate_payload(kind: str, payload: Any) -> None:
    """Check a robot-to-robot payload.

    The built-in kinds have a schema in ``copath.wire.payloads.PAYLOADS``; any other kind
    (a user controller's own, ``docs/reference/controllers.md``) must be a lower-case name, and its
    payload a map of plain values with finite numbers.
    """
    if not isinstance(kind, str) or not _KIND_RE.fullmatch(kind):
        raise WireError(f"message kind {kind!r} is not allowed; a kind is a lower-case name "
                        "(letters, digits, underscore; at most 64 characters)")
    if not isinstance(payload, dict):
        raise WireError(f"{kind}: payload must be a map, got {type(payload).__name__}")
    schema = PAYLOADS.get(kind)
    if schema is None:
        _check_plain(payload, kind)
        return
    for name, typ in schema.items():
        optional = name.endswith("?")
        key = name[:-1] if optional else name
        if key not in payload:
            if optional:
                continue
            raise WireError(f"{kind}: missing field {key!r}")
        if not _CHECKS[typ](payload[key]):
            raise WireError(f"{kind}.{key} = {payload[key]!r} is not a {typ}")
        if typ == "any":
            _check_plain(payload[key], f"{kind}.{key}")


_FREE_FORM = frozenset({"dict", "dict?", "any", "counts", "counts?"})
"""Field types whose maps ``to_plain`` rewrites (keys to strings) when packing; the other
fields go to the encoder as they are (numpy arrays and scalars through :func:`_enc_hook`)."""

_PLANS: dict[type, tuple[tuple[str, bool], ...]] = {}
"""Each record class's fields in declaration order, with whether the field is free-form."""


def _plan(cls: type) -> tuple[tuple[str, bool], ...]:
    plan = _PLANS.get(cls)
    if plan is None:  # dataclasses.fields() costs more than the packing of a small record
        plan = _PLANS[cls] = tuple((f.name, cls.FIELDS.get(f.name) in _FREE_FORM) for f in dataclasses.fields(cls))
    return plan


def _enc_hook(x: Any) -> Any:
    """numpy arrays and scalars as ``to_plain`` gives them (lists, Python numbers)."""
    if hasattr(x, "tolist"):
        return x.tolist()
    raise TypeError(f"can not serialize {type(x).__name__!r} object")


_ENC = msgspec.msgpack.Encoder(enc_hook=_enc_hook)
"""msgpack, as ``msgpack.packb(..., use_bin_type=True)`` writes the same values (the same bytes:
tests/unit/test_wire_msgspec.py)."""


class _Record:
    """Mixin: pack/unpack with version, tag and field-type validation."""

    TYPE: ClassVar[str]
    FIELDS: ClassVar[dict[str, str]]

    def to_dict(self) -> dict[str, Any]:
        d = {n: to_plain(getattr(self, n)) for n, _ in _plan(type(self))}
        d["v"] = WIRE_VERSION
        d["type"] = self.TYPE
        return self._ordered(d)

    def _ordered(self, d: dict[str, Any]) -> dict[str, Any]:
        """``d`` with maps whose order must not depend on insertion order sorted."""
        return d

    def pack(self) -> bytes:
        """The msgpack bytes of :meth:`to_dict`, encoded by msgspec: the free-form maps go
        through ``to_plain``, the typed fields straight to the encoder."""
        d = {n: to_plain(getattr(self, n)) if free else getattr(self, n) for n, free in _plan(type(self))}
        d["v"] = WIRE_VERSION
        d["type"] = self.TYPE
        return _ENC.encode(self._ordered(d))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]):
        for name, typ in cls.FIELDS.items():
            if name not in d:
                raise WireError(f"{cls.TYPE}: missing field {name!r}")
            if not _CHECKS[typ](d[name]):
                raise WireError(f"{cls.TYPE}.{name} = {d[name]!r} is not a {typ}")
        return cls(**{k: d[k] for k in cls.FIELDS})


@dataclass(frozen=True)
class Obs(_Record):
    """Simulator -> one robot: its pose estimate and sensors at tick k (key robot/<name>/obs)."""

    TYPE: ClassVar[str] = "obs"
    FIELDS: ClassVar[dict[str, str]] = {"k": "int", "t": "float", "pose": "floats", "ranges": "distances?",
                                        "expect": "counts?", "meas": "dict?", "down": "strs?"}
    k: int
    t: float
    pose: list[float]
    """True pose (ideal sensing, plus ``[noise] pose_std``), or with a ``[sensing]`` profile
    the raw reading: latest position fix and heading measurement delivered."""
    ranges: list[float] | None = None
    expect: dict[str, int] | None = None
    """Lockstep barrier: how many peer messages each sender had sent this robot's way
    (broadcasts plus direct ones) by the end of the previous tick."""
    meas: dict[str, Any] | None = None
    """Measurements delivered since the previous observation (None: ideal sensing):
    ``odom`` [[t0, t1, u...]] measured body velocities held over [t0, t1];
    ``fixes`` [[t_taken, x, y]]; ``headings`` [[t_taken, theta]] (sim/sensing.py)."""
    down: list[str] | None = None
    """Lockstep: the robots whose liveliness token is gone at tick k as the simulator applies it
    (a process died, froze or was killed by ``run.kills``; back when its token is): every robot
    takes token losses from here, at the tick the simulator applied them, as the barrier
    sequences messages (docs/reference/faults.md, "When the others learn of a loss").
    None in realtime, where each robot's own liveliness watch says it as it happens."""

    _MEAS_WIDTH: ClassVar[dict[str, tuple[int, ...]]] = {"odom": (4, 5), "fixes": (3,), "headings": (2,)}

    def _ordered(self, d: dict[str, Any]) -> dict[str, Any]:
        if d["expect"] is not None:  # sender order, not arrival order: equal runs give equal bytes
            d["expect"] = dict(sorted(d["expect"].items()))
        if d["down"] is not None:
            d["down"] = sorted(d["down"])
        return d

    @classmethod
    def from_dict(cls, d):
        rec = super().from_dict(d)
        if rec.meas is not None:
            cls._check_meas(rec.meas)
        return rec

    @classmethod
    def _check_meas(cls, meas: dict) -> None:
        for key, widths in cls._MEAS_WIDTH.items():
            rows = meas.get(key)
            if not _CHECKS["matrix"](rows) or any(len(r) not in widths for r in rows):
                raise WireError(f"obs.meas.{key} = {rows!r} must be rows of {widths} numbers")


@dataclass(frozen=True)
class Estimate(_Record):
    """Robot -> recorder: its pose estimate at tick k (key robot/<name>/estimate)."""

    TYPE: ClassVar[str] = "estimate"
    FIELDS: ClassVar[dict[str, str]] = {"k": "int", "t": "float", "x": "floats", "cov": "matrix", "nis": "floats",
                                        "nis_dof": "ints", "counts": "dict"}
    k: int
    t: float
    x: list[float]
    """x, y, theta [m, m, rad] and the heading sensor's bias [rad] (copath.estimation.PoseEKF)."""
    cov: list[list[float]]
    """4 x 4 covariance of x."""
    nis: list[float] = field(default_factory=list)
    """Normalised innovation squared of each measurement first fused (or gated) this step."""
    nis_dof: list[int] = field(default_factory=list)
    """Its degrees of freedom (2: position fix, 1: heading)."""
    counts: dict[str, int] = field(default_factory=dict)
    """Cumulative ``accepted``, ``rejected`` (chi-square gate) and ``late`` measurements."""


@dataclass(frozen=True)
class Command(_Record):
    """Robot -> simulator: body velocities for tick k (key robot/<name>/cmd)."""

    TYPE: ClassVar[str] = "cmd"
    FIELDS: ClassVar[dict[str, str]] = {"k": "int", "t": "float", "cmd": "floats", "solve_ms": "float",
                                        "sent": "counts"}
    k: int
    t: float
    cmd: list[float]
    solve_ms: float = 0.0
    sent: dict[str, int] = field(default_factory=dict)
    """Peer messages sent so far: ``"*"`` broadcasts, and per receiver name direct ones."""

    def _ordered(self, d: dict[str, Any]) -> dict[str, Any]:
        d["sent"] = dict(sorted(d["sent"].items()))
        return d


@dataclass(frozen=True)
class Telemetry(_Record):
    """Robot -> recorder: the controller's per-step telemetry (key robot/<name>/telemetry)."""

    TYPE: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[dict[str, str]] = {"k": "int", "t": "float", "data": "dict"}
    k: int
    t: float
    data: dict[str, Any]


@dataclass(frozen=True)
class Truth(_Record):
    """Simulator -> recorder: the world at tick k (key sim/truth). Robots never read it."""

    TYPE: ClassVar[str] = "truth"
    FIELDS: ClassVar[dict[str, str]] = {
        "k": "int",
        "t": "float",
        "names": "strs",
        "poses": "matrix",
        "commands": "matrix",
        "violated": "bools",
        "wheel_max": "floats",
        "clearance": "distances?",
        "obstacles": "any",
    }
    k: int
    t: float
    names: list[str]
    poses: list[list[float]]
    commands: list[list[float]]
    """Commands applied over [t, t + dt] after saturation."""
    violated: list[bool]
    """Whether each robot's requested command exceeded its model's limits."""
    wheel_max: list[float]
    """Largest wheel rim speed of the applied command [m/s]."""
    clearance: list[float] | None = None
    """Distance from each robot's disc to the nearest obstacle [m] (None: no obstacles)."""
    obstacles: Any = None
    """Obstacle polygons at t (list of lists of [x, y]) or None."""


@dataclass(frozen=True)
class PeerEnvelope(_Record):
    """Robot -> robot message (key peer/<sender>/all or peer/<sender>/to/<receiver>)."""

    TYPE: ClassVar[str] = "peer"
    FIELDS: ClassVar[dict[str, str]] = {
        "sender": "str",
        "seq": "int",
        "stamp": "float",
        "kind": "str",
        "pos": "floats",
        "payload": "dict",
        "cov": "floats?",
        "vel": "floats?",
        "pos_t": "float?",
        "acks": "stamps?",
    }
    sender: str
    seq: int
    """Per-sender sequence number (counts every message the sender published)."""
    stamp: float
    """Sender's clock [s]."""
    kind: str
    pos: list[float]
    """Sender's own position estimate [x, y] (range-limited graphs, Def. 10)."""
    payload: dict[str, Any]
    cov: list[float] | None = None
    """Covariance [Pxx, Pxy, Pyy] of ``pos`` when the sender runs an estimator, else None."""
    vel: list[float] | None = None
    """Sender's world-frame velocity [xdot, ydot, thetadot] ([m/s, m/s, rad/s]) under the command
    it applies from ``stamp`` on (its own acceleration-limited command, (3.1)/(3.3)); None in
    logs written before the field existed. The safety filter predicts the sender with it."""
    pos_t: float | None = None
    """Sender's clock [s] when ``pos`` was true, when that is before ``stamp``: a realtime robot
    steps on its own timer with an observation up to a period old (docs/reference/safety.md,
    "Late commands"); None when it is the stamp (lockstep) and in logs written before the
    field existed. The safety filter dates the position (and ``vel``'s arc) from it."""
    acks: dict[str, float] | None = None
    """Committed plans only: for each robot whose envelopes the sender's safety filter holds, the
    time of the plan it holds (that envelope's ``pos_t``, or its stamp), so the robot keeps no
    older plan (docs/reference/safety.md, "Acknowledged plans"); None without committed plans and
    in logs written before the field existed."""

    @classmethod
    def from_dict(cls, d):
        if "vel" not in d or "pos_t" not in d or "acks" not in d:  # written before the fields existed
            d = {"vel": None, "pos_t": None, "acks": None, **d}
        rec = super().from_dict(d)
        validate_payload(rec.kind, rec.payload)
        if len(rec.pos) != 2:
            raise WireError(f"peer.pos = {rec.pos!r} must be [x, y]")
        if rec.cov is not None and len(rec.cov) != 3:
            raise WireError(f"peer.cov = {rec.cov!r} must be [Pxx, Pxy, Pyy]")
        if rec.vel is not None and len(rec.vel) != 3:  # finiteness: the floats? field check
            raise WireError(f"peer.vel = {rec.vel!r} must be [xdot, ydot, thetadot], finite")
        return rec


@dataclass(frozen=True)
class Start(_Record):
    """Simulator -> all: the run starts; wall-clock origin for realtime clocks (key sim/start)."""

    TYPE: ClassVar[str] = "start"
    FIELDS: ClassVar[dict[str, str]] = {"wall_t0": "float", "dt": "float", "clock": "str"}
    wall_t0: float
    dt: float
    clock: str


@dataclass(frozen=True)
class End(_Record):
    """Simulator -> all: the run is over (key sim/end)."""

    TYPE: ClassVar[str] = "end"
    FIELDS: ClassVar[dict[str, str]] = {"k": "int", "t": "float", "reason": "str", "ok": "bool"}
    k: int
    t: float
    reason: str
    ok: bool = True


@dataclass(frozen=True)
class Event(_Record):
    """Something worth a line in the log (key <proc>/event): missed ticks, lost robots, rejects."""

    TYPE: ClassVar[str] = "event"
    FIELDS: ClassVar[dict[str, str]] = {"t": "float", "source": "str", "what": "str", "detail": "dict"}
    t: float
    source: str
    what: str
    detail: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Stats(_Record):
    """A process's closing account (key stats/<proc>)."""

    TYPE: ClassVar[str] = "stats"
    FIELDS: ClassVar[dict[str, str]] = {"proc": "str", "published": "int", "counters": "dict"}
    proc: str
    published: int
    """Messages this process published under the run prefix, this one excluded."""
    counters: dict[str, Any] = field(default_factory=dict)


RECORD_TYPES: dict[str, type[_Record]] = {
    c.TYPE: c for c in (Obs, Estimate, Command, Telemetry, Truth, PeerEnvelope, Start, End, Event, Stats)
}


_MAX = sys.float_info.max
_FINITE = Union[int, Annotated[float, msgspec.Meta(ge=-_MAX, le=_MAX)]]
"""``float`` of ``_CHECKS``: an int, or a float that is not NaN or infinite (NaN fails both bounds)."""
_DISTANCE = Union[int, Annotated[float, msgspec.Meta(ge=-_MAX)]]
"""A finite number or +inf."""

_PLAIN: Any = Union[None, bool, int, float, str]
for _ in range(_MAX_DEPTH + 2):
    _PLAIN = Union[None, bool, int, float, str, list[_PLAIN], dict[str, _PLAIN]]
"""Plain values with string map keys, nested at most ten levels: what the free-form fields
take on the fast path (deeper values, other keys, bytes or extension types: the Python path)."""

_PLAIN_FINITE: Any = Union[None, bool, int, Annotated[float, msgspec.Meta(ge=-_MAX, le=_MAX)], str]
for _ in range(_MAX_DEPTH):
    _PLAIN_FINITE = Union[None, bool, int, Annotated[float, msgspec.Meta(ge=-_MAX, le=_MAX)], str,
                          list[_PLAIN_FINITE], dict[str, _PLAIN_FINITE]]
"""What :func:`_check_plain` accepts, checked in C: plain values with string map keys and
finite floats, a value at most ``_MAX_DEPTH`` levels below the field (an empty list or map at
the last level, which the Python check also accepts, takes the Python path). A payload's
``any`` fields are decoded with it, so a role_state envelope's relayed tables (known, claims,
rulings) are no longer walked in Python (docs/journal/performance.md, over Zenoh, third pass (P23))."""

_FAST_TYPES: dict[str, Any] = {
    "float": _FINITE,
    "int": int,
    "bool": bool,
    "str": str,
    "floats": list[_FINITE],
    "ints": list[int],
    "points": list[Annotated[list[_FINITE], msgspec.Meta(min_length=2, max_length=2)]],
    "any": _PLAIN,
    "dict": dict[str, _PLAIN],
    "dict?": Optional[dict[str, _PLAIN]],
    "floats?": Optional[list[_FINITE]],
    "float?": Optional[_FINITE],
    "strs": list[str],
    "strs?": Optional[list[str]],
    "bools": list[bool],
    "matrix": list[list[_FINITE]],
    "distances?": Optional[list[_DISTANCE]],
    "counts": dict[str, int],
    "counts?": Optional[dict[str, int]],
    "stamps?": Optional[dict[str, _FINITE]],
}
"""msgspec's type for each field type of ``_CHECKS``: it accepts a subset of what the check
accepts (map keys are strings, as msgpack's ``strict_map_key`` wants them at every level)
and decodes to the same values (ints stay ints)."""

_FAST_LENGTH = {(PeerEnvelope, "pos"): 2, (PeerEnvelope, "cov"): 3, (PeerEnvelope, "vel"): 3}
"""Fixed list lengths that ``from_dict`` checks after the field types."""

_OPTIONAL_LATER = {(PeerEnvelope, "vel"), (PeerEnvelope, "pos_t"), (PeerEnvelope, "acks")}
"""Fields added after logs were written without them: absent means None."""


class _Head(msgspec.Struct, gc=False):
    """Version, tag and (peer envelopes) kind of any record; the other fields are skipped in C."""

    v: Any = None
    type: Any = None
    kind: Any = None


_HEAD = msgspec.msgpack.Decoder(_Head)


def _fast_decoder(cls: type[_Record]) -> msgspec.msgpack.Decoder:
    """A decoder of ``cls``'s fields into a dict (a ``TypedDict`` twin of ``FIELDS``)."""
    names = [f.name for f in dataclasses.fields(cls)]
    if names != list(cls.FIELDS) or hasattr(cls, "__post_init__") or hasattr(cls, "__slots__"):
        raise TypeError(f"{cls.__name__}: FIELDS must list its fields in order, without __post_init__ or slots")
    spec = {}
    for name, typ in cls.FIELDS.items():
        t = _FAST_TYPES[typ]
        n = _FAST_LENGTH.get((cls, name))
        if n is not None:
            t = Annotated[list[_FINITE], msgspec.Meta(min_length=n, max_length=n)]
            if typ.endswith("?"):
                t = Optional[t]
        spec[name] = NotRequired[t] if (cls, name) in _OPTIONAL_LATER else t
    return msgspec.msgpack.Decoder(TypedDict(f"_{cls.__name__}Wire", spec))


_FAST: dict[str, tuple[type[_Record], msgspec.msgpack.Decoder]] = {
    tag: (cls, _fast_decoder(cls)) for tag, cls in RECORD_TYPES.items()}

_new = object.__new__
_set = object.__setattr__


class _PayloadCheck(NamedTuple):
    schema: dict[str, str]
    """The schema it was built from (``PAYLOADS[kind]``)."""
    decoder: msgspec.msgpack.Decoder
    """Decodes a whole peer envelope, checking its payload's fields, the ``any`` ones with :data:`_PLAIN_FINITE`."""


_PAYLOAD_CHECKS: dict[str, _PayloadCheck | None] = {}


def _payload_check(kind: str) -> _PayloadCheck | None:
    """The msgspec check of a registered kind's payload (None: the kind has no schema, or
    its name is not a kind; Python checks it)."""
    schema = PAYLOADS.get(kind)
    got = _PAYLOAD_CHECKS.get(kind)
    if got is not None and (got.schema is schema or got.schema == schema):
        return got
    if schema is None or not _KIND_RE.fullmatch(kind):
        return None
    fields = []
    for name, typ in schema.items():
        optional = name.endswith("?")
        key = name[:-1] if optional else name
        t = _PLAIN_FINITE if typ == "any" else _FAST_TYPES[typ]
        fields.append((key, t, msgspec.UNSET) if optional else (key, t))
    fields.sort(key=lambda f: len(f) == 3)  # required first
    payload = msgspec.defstruct(f"_{kind}Payload", fields, gc=False)
    envelope = msgspec.defstruct(f"_{kind}Envelope", [("payload", payload)], gc=False)
    got = _PAYLOAD_CHECKS[kind] = _PayloadCheck(schema, msgspec.msgpack.Decoder(envelope))
    return got


def _map_len(data: bytes | bytearray | memoryview) -> int:
    """Number of entries of the msgpack map ``data`` starts with (-1: not a map header)."""
    b = data[0]
    if 0x80 <= b <= 0x8F:
        return b & 0x0F
    if b == 0xDE:
        return int.from_bytes(data[1:3], "big")
    if b == 0xDF:
        return int.from_bytes(data[1:5], "big")
    return -1


def unpack(data: bytes | bytearray | memoryview):
    """Decode and validate any record; raises WireError.

    msgspec decodes the record's fields into a dict and checks their types in C (a peer
    envelope's payload too, for a kind with a schema); a record it refuses goes through
    :func:`unpack_checked`, which accepts or refuses it with the Python checks and names the
    reason. The record is made from the checked dict without running ``__init__`` again
    (the frozen dataclasses have no ``__post_init__``)."""
    try:
        head = _HEAD.decode(data)
        if head.v == WIRE_VERSION and type(head.type) is str:
            fast = _FAST.get(head.type)
            if fast is not None:
                cls, dec = fast
                d = dec.decode(data)
                if _map_len(data) != len(d) + 2:  # other keys (skipped unread by the twin): the Python path
                    return unpack_checked(data)
                if cls is PeerEnvelope:
                    if "vel" not in d:
                        d["vel"] = None
                    if "pos_t" not in d:
                        d["pos_t"] = None
                    if "acks" not in d:
                        d["acks"] = None
                    check = _payload_check(head.kind) if type(head.kind) is str else None
                    if check is None:
                        validate_payload(d["kind"], d["payload"])
                    else:
                        check.decoder.decode(data)  # the "any" fields too (_PLAIN_FINITE)
                elif cls is Obs and d["meas"] is not None:
                    Obs._check_meas(d["meas"])
                rec = _new(cls)
                _set(rec, "__dict__", d)
                return rec
    except (msgspec.DecodeError, WireError):
        pass
    return unpack_checked(data)


def unpack_checked(data: bytes | bytearray | memoryview):
    """Decode with msgpack and validate with the Python checks; raises WireError naming
    the field and the reason (the reference :func:`unpack` falls back on)."""
    try:
        d = msgpack.unpackb(bytes(data), raw=False)
    except Exception as exc:  # msgpack raises several exception types
        raise WireError(f"not a msgpack record: {exc}") from None
    if not isinstance(d, dict):
        raise WireError("record must be a msgpack map")
    if d.get("v") != WIRE_VERSION:
        raise WireError(f"wire version {d.get('v')!r} is not supported (expected {WIRE_VERSION})")
    tag = d.get("type")
    cls = RECORD_TYPES.get(tag) if isinstance(tag, str) else None  # a list or map tag is no record type either
    if cls is None:
        raise WireError(f"unknown record type {d.get('type')!r}")
    return cls.from_dict(d)

