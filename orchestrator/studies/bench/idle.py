"""A controller that does (almost) nothing: the floor of a lockstep fleet (``copath bench floor``).

It commands a constant velocity and, with ``message = true``, broadcasts one small message
per step of the consensus family's shape (Sec. 5.5, Eq. (5.42): s, s-dot, s_d), without
reading what it hears. Run in E5.4's place, with the safety filter and detours off, it leaves of an
agent's step only what the design itself costs: the observation received, the runtime's
bookkeeping, the records packed and published, and Zenoh's threads
(docs/journal/performance.md, the floor of the design (P26)).

It lives in its own module, imported by the agents by its import path
(``orchestrator.studies.bench.idle:build``), so an agent imports nothing of the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from copath.control import Observation, Outgoing, PeerMessage, RobotContext, StepResult, controller

__all__ = ["IdleConfig", "Idle", "build", "PAYLOADS"]

PAYLOADS = {"idle_state": {"s": "float", "sdot": "float", "s_d": "float"}}
"""Its one message kind, the size of the consensus family's ``coord_state`` (Eq. (5.42))."""


@dataclass(frozen=True)
class IdleConfig:
    v: float = 0.0
    """Constant forward speed commanded [m/s] (0: the robots stand still and never meet)."""
    omega: float = 0.0
    """Constant turn rate commanded [rad/s] (unicycles; ignored by omni robots)."""
    message: bool = False
    """Broadcast one ``idle_state`` message per step to the neighbours."""
    s_d: float = 0.0
    """Carried in the message only (a scenario's robots give it)."""


class Idle:
    """Constant command; optionally one message per step; reads nothing it hears."""

    def __init__(self, ctx: RobotContext, cfg: IdleConfig) -> None:
        self.cfg = cfg
        size = 3 if ctx.model.kind == "omni" else 2
        self.u = np.zeros(size)
        self.u[0] = cfg.v
        if size == 2:
            self.u[1] = cfg.omega

    def step(self, obs: Observation, messages: list[PeerMessage]) -> StepResult:
        out = [Outgoing("idle_state", {"s": float(obs.t), "sdot": self.cfg.v, "s_d": self.cfg.s_d})] \
            if self.cfg.message else []
        return StepResult(command=self.u.copy(), messages=out, telemetry={})


@controller(config=IdleConfig, payloads=PAYLOADS)
def build(ctx: RobotContext, cfg: IdleConfig) -> Idle:
    return Idle(ctx, cfg)
