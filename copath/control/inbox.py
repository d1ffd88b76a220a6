"""The newest message of every neighbour, per kind (the controller kit's inbox).

Every distributed controller of the dissertation keeps, for each neighbour j, only the
newest information it has received: the coordination state (s_j, sdot_j) of the
consensus (5.42), the assumed trajectory of the distributed MPC (Algorithm 5.1), the
leader's plan of the leader-following scheme (Sec. 5.3.3), the role state of Chapter 6.
Messages can arrive late, twice or out of order (the fault layer delays, duplicates and
reorders them), so "newest" means the largest sender stamp, not the last delivered.

:class:`LatestMessages` is that bookkeeping, written once for every controller::

    inbox = LatestMessages(kinds=("coord_state",))
    ...
    def step(self, obs, messages):
        inbox.update(messages, obs.t)
        for sender, got in inbox.fresh("coord_state", obs.t, max_age=2.0).items():
            s_j = got.payload["s"]; age = got.age(obs.t)

Age of information
------------------
A :class:`Received` entry knows two ages at a later receiver time t:

- :meth:`Received.age`: ``message.age + (t - received_at)``, the age the transport
  measured at delivery plus the time the message has been held since (the age of
  information of the leader's plan, Sec. 5.3.3);
- :meth:`Received.since_stamp`: ``t - stamp``, the receiver clock minus the sender's
  stamp (equal to :meth:`~Received.age` when the clocks are synchronised, as they are
  once at start-up).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, Mapping

from .contract import PeerMessage

__all__ = ["Received", "LatestMessages"]


@dataclass(frozen=True)
class Received:
    """One kept message and the receiver's clock when it was taken in."""

    message: PeerMessage
    received_at: float
    """Receiver's clock at the step that took the message in [s]."""
    value: Any = None
    """The message decoded once by the inbox's ``decode`` (None without one)."""

    @property
    def sender(self) -> str:
        return self.message.sender

    @property
    def kind(self) -> str:
        return self.message.kind

    @property
    def stamp(self) -> float:
        """Sender's clock at sending [s]."""
        return self.message.stamp

    @property
    def payload(self) -> Mapping[str, Any]:
        return self.message.payload

    @property
    def position(self) -> tuple[float, float] | None:
        """Sender's position estimate carried with the message (range-limited graphs, Def. 10)."""
        return self.message.position

    def age(self, t: float) -> float:
        """Age of information at receiver time t: age at delivery plus time held [s]."""
        return self.message.age + (t - self.received_at)

    def since_stamp(self, t: float) -> float:
        """Receiver time t minus the sender's stamp [s]."""
        return t - self.message.stamp


class LatestMessages:
    """Keeps the newest message per (sender, kind), by sender stamp.

    A message whose stamp is not larger than the kept one of the same sender and kind
    (a late, reordered or duplicated copy) is ignored.

    Parameters
    ----------
    kinds : iterable of str, optional
        Message kinds to keep; others are ignored. None keeps every kind.
    senders : iterable of str, optional
        Senders to keep (e.g. the fixed-graph neighbours); None keeps every sender.
    accept : callable (PeerMessage) -> bool, optional
        Extra check of a newer message (e.g. a payload that can be used); a message it
        rejects is ignored as if it had not arrived, so the kept one stays.
    decode : callable (PeerMessage) -> object, optional
        Turns a newer message into what the controller uses (an assumed trajectory, a
        neighbour's state), once, stored as :attr:`Received.value`. A message it cannot
        decode (KeyError, TypeError or ValueError) is ignored like one ``accept`` refuses.
    """

    def __init__(
        self,
        kinds: Iterable[str] | None = None,
        senders: Iterable[str] | None = None,
        accept: Callable[[PeerMessage], bool] | None = None,
        decode: Callable[[PeerMessage], Any] | None = None,
    ) -> None:
        self._kinds = None if kinds is None else frozenset(kinds)
        self._senders = None if senders is None else frozenset(senders)
        self._accept = accept
        self._decode = decode
        self._kept: dict[tuple[str, str], Received] = {}

    def update(self, inbox: Iterable[PeerMessage], t: float, lost: Iterable[str] = ()) -> list[Received]:
        """Take in the messages of one step at receiver time t; returns the newly kept
        entries in arrival order (an entry may be replaced later in the same list).
        ``lost`` (``Observation.lost``): robots known to be gone, whose kept messages are
        forgotten, so the controller's graph no longer has them."""
        for sender in lost:
            if any(k[0] == sender for k in self._kept):
                self.forget(sender)
        new = []
        for m in inbox:
            if self._kinds is not None and m.kind not in self._kinds:
                continue
            if self._senders is not None and m.sender not in self._senders:
                continue
            key = (m.sender, m.kind)
            old = self._kept.get(key)
            if old is not None and m.stamp <= old.message.stamp:
                continue  # late, reordered or duplicated: keep the newest
            if self._accept is not None and not self._accept(m):
                continue
            value = None
            if self._decode is not None:
                try:
                    value = self._decode(m)
                except (KeyError, TypeError, ValueError):
                    continue
            got = Received(m, float(t), value)
            self._kept[key] = got
            new.append(got)
        return new

    def get(self, sender: str, kind: str) -> Received | None:
        """The kept message of ``sender`` and ``kind``, or None."""
        return self._kept.get((sender, kind))

    def of_kind(self, kind: str) -> dict[str, Received]:
        """Sender -> kept message of ``kind``, in the order the senders were first heard."""
        return {s: r for (s, k), r in self._kept.items() if k == kind}

    def fresh(self, kind: str, t: float, max_age: float, by: str = "stamp") -> dict[str, Received]:
        """Like :meth:`of_kind`, without messages older than ``max_age`` at time t.

        ``by = "stamp"`` measures t - stamp (:meth:`Received.since_stamp`), ``"age"`` the
        age of information (:meth:`Received.age`), ``"receipt"`` the time since the
        message was taken in (t - received_at).
        """
        if by not in _AGES:
            raise ValueError(f"by = {by!r} is not allowed; choose one of {sorted(_AGES)}")
        age = _AGES[by]
        return {s: r for s, r in self.of_kind(kind).items() if age(r, t) <= max_age}

    def forget(self, sender: str | None = None, kind: str | None = None) -> None:
        """Drop kept messages of ``sender`` and/or ``kind`` (both None: everything)."""
        self._kept = {key: r for key, r in self._kept.items()
                      if not ((sender is None or key[0] == sender) and (kind is None or key[1] == kind))}

    def __len__(self) -> int:
        return len(self._kept)

    def __iter__(self) -> Iterator[Received]:
        return iter(list(self._kept.values()))

    def __contains__(self, key: tuple[str, str]) -> bool:
        return key in self._kept


_AGES: dict[str, Callable[[Received, float], float]] = {
    "stamp": Received.since_stamp,
    "age": Received.age,
    "receipt": lambda r, t: t - r.received_at,
}
