"""Stage "trust": a peer envelope's stamp is checked against the receiver's clock before
anything else sees it (docs/reference/faults.md, "Every receiver validates" and "Rejected
messages and the lockstep barrier"; :class:`copath.wire.trust.StampWindow`)."""

from __future__ import annotations

from copath.scenario import Scenario
from copath.wire.messages import PeerEnvelope, WireError
from copath.wire.trust import RejectLog, StampWindow

__all__ = ["TrustStage"]


class TrustStage:
    """The stamp window of one robot's received peer envelopes.

    Reads: each arriving envelope's stamp; the step clock (:meth:`advance`).
    Writes: :attr:`reject_log` (a refused stamp, once per message).

    Before the first step there is no clock: envelopes that arrive then (a robot restarted
    mid-run) are kept (:meth:`keep_early`) and checked at the first step's clock."""

    name = "trust"

    def __init__(self, scenario: Scenario) -> None:
        net = scenario.network
        self.window = StampWindow.for_run(scenario.run.dt, net.delay_ms, net.jitter_ms)
        self.reject_log = RejectLog()
        """Where refused stamps are counted (a node shares its link's, :meth:`count_rejects_in`)."""
        self.now = 0.0
        """Controller time of the latest step [s] (0 before the first); never goes back."""
        self._early: list[PeerEnvelope] | None = []

    @property
    def started(self) -> bool:
        """Whether the first step has run (there is a clock to check stamps against)."""
        return self._early is None

    def count_rejects_in(self, log: RejectLog) -> None:
        self.reject_log = log

    def keep_early(self, env: PeerEnvelope) -> bool:
        """Keep ``env`` for the first step when there is no clock yet; False once there is."""
        if self._early is None:
            return False
        self._early.append(env)
        return True

    def advance(self, now: float) -> list[PeerEnvelope]:
        """Move the clock to ``now`` (never back); at the first step, return the envelopes
        kept before it, to be received now."""
        self.now = max(self.now, float(now))
        if self._early is None:
            return []
        early, self._early = self._early, None
        return early

    def admit(self, env: PeerEnvelope, where: str, record: bool = True) -> bool:
        """Whether ``env``'s stamp lies in the window at the current clock; a refused one is
        counted in :attr:`reject_log` (``record``) as ``peer/<sender> (<where>)``."""
        try:
            self.window.check(env.stamp, self.now)
        except WireError as exc:
            if record:
                self.reject_log.add(f"peer/{env.sender} ({where})", str(exc))
            return False
        return True
