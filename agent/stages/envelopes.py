"""Stage "envelopes": the command the robot applies and the envelopes its messages go out in
(docs/reference/faults.md, "Every receiver validates": what a receiver reads of an envelope)."""

from __future__ import annotations

import numpy as np

from copath.models import limit_change, world_velocity_list
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
    numbers; :attr:`sent` (per recipient, the lockstep barrier's ``expect``)."""

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

    def send(self, now: float, pose: np.ndarray, command: list[float], messages,
             cov: list[float] | None, pos_t: float | None = None,
             acks: dict[str, float] | None = None) -> tuple[list[tuple[str, PeerEnvelope]], list[float]]:
        """(key, envelope) of each outgoing message, and the world velocity they carry;
        ``pos_t``: when ``pose`` was true, if before ``now`` (else None); ``acks``: the safety
        filter's acknowledgements of the plans it holds (committed plans only, else None)."""
        self.applied = limit_change(self.model, self.applied, self.model.saturate(command)[0], self.dt)
        vel = world_velocity_list(self.model, float(pose[2]), self.applied)
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
