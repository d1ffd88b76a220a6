"""Stage "envelopes": the command the robot applies and the envelopes its messages go out in
(docs/reference/faults.md, "Every receiver validates": what a receiver reads of an envelope)."""

from __future__ import annotations

import numpy as np

from copath.models import body_velocity_between, limit_change, world_velocity_list
from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.messages import PeerEnvelope, to_plain

__all__ = ["EnvelopeStage"]


class EnvelopeStage:
    """One robot's outgoing peer envelopes.

    Reads: the final command, the robot's pose, the controller's messages, the position
    covariance (with an estimator).
    Writes: the applied command (saturated and, with an acceleration limit, rate-limited as
    the simulator does) whose world velocity travels in every envelope; the sequence
    numbers; :attr:`sent` (per recipient, the lockstep barrier's ``expect``).

    A process that joined a run in progress (a restart, :meth:`rejoined`) does not know what its
    base applies: the killed process's last command, braked by the simulator since. Until it has
    seen its base move (:meth:`observe`: the newest odometry segment, else two observed poses),
    its envelopes carry no velocity, so it promises nothing (committed plans) and its neighbours
    bound it by its limits. Starting from rest instead, its first envelopes promised a robot at
    0.03 m/s where the base still drove at 0.15 m/s, and its own safety filter braked it to keep
    that promise: E5.4's r4, back 0.2 s after a kill, fell 0.16 m behind its team and held the
    robots behind it back (docs/journal/faults.md, "A restarted robot's first promise")."""

    name = "envelopes"

    def __init__(self, scenario: Scenario, name: str, keys: Keys) -> None:
        spec = scenario.robot(name)
        self.robot = name
        self.keys = keys
        self.dt = scenario.run.dt
        self.model = spec.model
        self.seq = 0
        self.sent: dict[str, int] = {"*": 0}
        """Envelopes sent so far: broadcasts under ``*``, direct ones per recipient."""
        self.applied = np.zeros(spec.model.command_size)
        """The command the robot applies, for the velocity in its envelopes."""
        self.known = True
        """Whether :attr:`applied` is what the base applies (False after :meth:`rejoined` until
        :meth:`observe` has seen the base move)."""
        self._seen: tuple[float, np.ndarray] | None = None
        """A rejoined process's first observed pose and its time, for :meth:`observe`."""

    def rejoined(self) -> None:
        """This process joined a run in progress: what its base applies is not known yet."""
        self.known, self._seen = False, None

    def observe(self, obs_t: float, pose, odom=()) -> None:
        """While :attr:`known` is False: take :attr:`applied` from what the robot observes of its
        base, the body velocities of the newest odometry segment (``[t0, t1, u...]``) or, without
        odometry, the motion between two observed poses (``obs_t`` apart) as body velocities."""
        if self.known:
            return
        n = len(self.applied)
        if odom:
            u = [float(x) for x in odom[-1][2:2 + n]]
        elif self._seen is None:
            self._seen = (float(obs_t), np.array(pose, dtype=float))
            return
        elif obs_t <= self._seen[0] + 1e-9:
            return  # the same observation again (a realtime step before the next one came)
        else:
            t0, p0 = self._seen
            uvw = body_velocity_between(p0, pose, float(obs_t) - t0)
            u = uvw.tolist() if n == 3 else [float(uvw[0]), float(uvw[2])]
        self.applied = np.asarray(u, dtype=float)
        self.known = True

    def send(self, now: float, pose: np.ndarray, command: list[float], messages,
             cov: list[float] | None, pos_t: float | None = None,
             acks: dict[str, float] | None = None) -> tuple[list[tuple[str, PeerEnvelope]], list[float] | None]:
        """(key, envelope) of each outgoing message, and the world velocity they carry (None while
        :attr:`known` is False);
        ``pos_t``: when ``pose`` was true, if before ``now`` (else None); ``acks``: the safety
        filter's acknowledgements of the plans it holds (committed plans only, else None)."""
        if self.known:
            self.applied = limit_change(self.model, self.applied, self.model.saturate(command)[0], self.dt)
            vel = world_velocity_list(self.model, float(pose[2]), self.applied)
        else:
            vel = None
        peers = []
        for m in messages:
            self.seq += 1
            env = PeerEnvelope(self.robot, self.seq, float(now), m.kind, [float(pose[0]), float(pose[1])],
                               to_plain(dict(m.payload)), None if cov is None else list(cov), vel, pos_t, acks)
            if m.to is None:
                peers.append((self.keys.peer_broadcast(self.robot), env))
                self.sent["*"] += 1
            else:
                for r in m.to:
                    peers.append((self.keys.peer_direct(self.robot, r), env))
                    self.sent[r] = self.sent.get(r, 0) + 1
        return peers, vel
