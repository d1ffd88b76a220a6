"""Fault layer on robot-to-robot links: delay, jitter, Bernoulli and burst loss, partitions.

Faults are applied where a message is received, from a seed: each directed link
(sender -> receiver) has its own random stream, consumed once per message in the
sender's sequence order, so a lockstep run is deterministic whatever the arrival timing.

Burst loss follows the Gilbert-Elliott model: a two-state Markov chain per link (good,
bad) with transition probabilities p_gb, p_bg per message and loss probability
``burst_loss`` in the bad state (on top of the Bernoulli ``loss``).

Delivery (:class:`FaultyInbox`): a message stamped ``stamp`` is released at
``stamp + delay + U(0, jitter)`` and delivered at the first receiver instant ``now`` with
``release <= now`` and ``stamp < now``: a message is never seen in the same control
instant it was sent, which makes lockstep runs independent of process scheduling.
"""

from __future__ import annotations

import heapq
import math
import zlib

import numpy as np

from copath.scenario import NetworkConfig

__all__ = ["LinkFaults", "FaultyInbox", "windows_between", "silence_outages", "SILENT_AFTER_S"]

SILENT_AFTER_S = 1.0
"""The default of the silence threshold: a robot from which a neighbour has heard no
robot-to-robot message for the run's transport lease (``run.lease_s``, default 1 s) counts as
lost there (``Observation.lost``), and a radio silence that long is handed to
``run.on_robot_failure``, so a frozen process and a silent radio are found alike, whatever
the lease (docs/reference/faults.md, "When a robot dies, freezes or goes quiet")."""


def _h(name: str) -> int:
    return zlib.crc32(name.encode())


class LinkFaults:
    """Per-receiver fault decisions for every incoming link."""

    def __init__(self, net: NetworkConfig, seed: int, receiver: str) -> None:
        self.net = net
        self.seed = int(seed)
        self.receiver = receiver
        self._rng: dict[str, np.random.Generator] = {}
        self._bad: dict[str, bool] = {}
        self.dropped = 0
        self.partitioned = 0
        self.silenced = 0
        self._clean = (net.loss == 0 and net.burst_p_gb == 0 and net.delay_ms == 0 and net.jitter_ms == 0
                       and not net.partitions and not getattr(net, "silence", ()))
        """A network without faults: every message is released at its stamp, no draws needed
        (the draws only feed fault decisions, so skipping them changes nothing)."""

    def _stream(self, sender: str) -> np.random.Generator:
        g = self._rng.get(sender)
        if g is None:
            g = np.random.default_rng(np.random.SeedSequence([self.seed, _h(sender), _h(self.receiver)]))
            self._rng[sender] = g
            self._bad[sender] = False
        return g

    def _partitioned(self, sender: str, stamp: float) -> bool:
        for p in self.net.partitions:
            if p.start_s <= stamp < p.end_s:
                for a, b in p.links:
                    if {a, b} == {sender, self.receiver}:
                        return True
        return False

    def release_time(self, sender: str, stamp: float) -> float | None:
        """Release time of a message, or None when the fault layer drops it."""
        if self._clean:
            return stamp
        g = self._stream(sender)
        u_loss, u_burst, u_state, u_jit = g.random(4)  # always 4 draws: streams stay aligned
        if self._partitioned(sender, stamp):
            self.partitioned += 1
            return None
        if any(s.robot in (sender, self.receiver) and s.start_s <= stamp < s.end_s for s in self.net.silence):
            self.silenced += 1  # the sender's or the receiver's radio is silent
            return None
        net = self.net
        lost = u_loss < net.loss
        if net.burst_p_gb > 0:
            bad = self._bad[sender]
            bad = (u_state >= net.burst_p_bg) if bad else (u_state < net.burst_p_gb)
            self._bad[sender] = bad
            lost = lost or (bad and u_burst < net.burst_loss)
        if lost:
            self.dropped += 1
            return None
        return stamp + (net.delay_ms + u_jit * net.jitter_ms) / 1000.0


def windows_between(net: NetworkConfig, t0: float, t1: float) -> list[tuple[str, dict]]:
    """Partition and radio-silence windows that open or close in [t0, t1):
    ``("partition_start" | "partition_end" | "silence_start" | "silence_end", detail)``, for
    the run's timeline of injected faults (docs/reference/faults.md)."""
    out = []
    for i, p in enumerate(net.partitions):
        detail = {"index": i, "links": [list(link) for link in p.links], "start_s": p.start_s, "end_s": p.end_s}
        if t0 - 1e-9 <= p.start_s < t1 - 1e-9:
            out.append(("partition_start", detail))
        if t0 - 1e-9 <= p.end_s < t1 - 1e-9:
            out.append(("partition_end", detail))
    for i, s in enumerate(getattr(net, "silence", ())):
        detail = {"index": i, "robot": s.robot, "start_s": s.start_s, "end_s": s.end_s}
        if t0 - 1e-9 <= s.start_s < t1 - 1e-9:
            out.append(("silence_start", detail))
        if t0 - 1e-9 <= s.end_s < t1 - 1e-9:
            out.append(("silence_end", detail))
    return out


def silence_outages(net: NetworkConfig, t0: float, t1: float,
                    after_s: float = SILENT_AFTER_S) -> list[tuple[str, dict]]:
    """Radio silences that become a robot's loss in [t0, t1): ``("silent", detail)`` at
    ``start_s + after_s`` for a window longer than ``after_s`` (no one has heard the robot
    for that long), ``("heard", detail)`` at its ``end_s``. The simulator applies
    ``run.on_robot_failure`` to them (docs/reference/faults.md)."""
    out = []
    for i, s in enumerate(getattr(net, "silence", ())):
        if s.end_s - s.start_s <= after_s:
            continue
        detail = {"index": i, "robot": s.robot, "start_s": s.start_s,
                  "end_s": s.end_s if math.isfinite(s.end_s) else None}
        if t0 - 1e-9 <= s.start_s + after_s < t1 - 1e-9:
            out.append(("silent", detail))
        if t0 - 1e-9 <= s.end_s < t1 - 1e-9:
            out.append(("heard", detail))
    return out


class FaultyInbox:
    """Receiver-side queue applying :class:`LinkFaults` and delivering by release time."""

    def __init__(self, faults: LinkFaults) -> None:
        self.faults = faults
        self._heap: list[tuple[float, int, float, object]] = []
        """(release time, arrival number, stamp, item): ordered by release, then arrival (the
        numbers are unique, so a stamp or an item is never compared); tuples compare in C."""
        self._n = 0

    def push(self, sender: str, stamp: float, item: object) -> bool:
        """Queue ``item``; False when the fault layer dropped it."""
        release = self.faults.release_time(sender, stamp)
        if release is None:
            return False
        self._n += 1
        heapq.heappush(self._heap, (max(release, stamp), self._n, stamp, item))
        return True

    def pop_ready(self, now: float, eps: float = 1e-9) -> list[object]:
        """Items whose release time has come (never one stamped at ``now`` itself)."""
        out, later = [], []
        heap = self._heap
        while heap and heap[0][0] <= now + eps:
            d = heapq.heappop(heap)
            if d[2] < now - eps:
                out.append(d[3])
            else:
                later.append(d)
        for d in later:
            heapq.heappush(heap, d)
        return out

    def __len__(self) -> int:
        return len(self._heap)
