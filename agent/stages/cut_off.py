"""The cut-off rule, runtime and safety side (docs/reference/faults.md, "When a robot dies,
freezes or goes quiet", *Cut off: it holds still*; docs/reference/safety.md, "A lost robot").

A robot that has lost every robot it has heard, at least one by silence, is cut off: most
likely its own radio went quiet. Under ``run.cut_off = "hold"`` its runtime commands zero
until it hears a robot again (:class:`HoldStage`), and every other robot's safety filter
keeps it as a static disc for at most :attr:`CutOffRule.silent_hold_s` after its last stamp.
A controller that handles being cut off itself opts out (its family's factory declares
``handles_cut_off = True``: the roles controller, docs/reference/ambiguities.md, robot lost
in role assignment (A38)); its share of the rule lives in that controller. The detection is the liveness
stage's (:class:`agent.stages.liveness.LivenessStage`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from copath.scenario import Scenario

__all__ = ["CutOffRule", "HoldStage", "silent_hold_s"]


def silent_hold_s(scenario: Scenario) -> float:
    """The latest a robot gone quiet holds itself still, after the stamp of its last message
    heard [s] (docs/reference/safety.md, "A lost robot"): its radio went quiet within one period after
    that stamp; the last message it received arrived within the network's largest delay
    (``delay_ms`` + ``jitter_ms``) after that and was read at its next step; it is cut off at
    the first step more than one lease (``run.lease_s``) later."""
    net, dt = scenario.network, scenario.run.dt
    return float(scenario.run.lease_s) + (net.delay_ms + net.jitter_ms) * 1e-3 + 3.0 * dt


@dataclass(frozen=True)
class CutOffRule:
    """One robot's reading of the scenario's cut-off rule (``run.cut_off``)."""

    mode: str
    """``run.cut_off``: ``hold`` (a cut-off robot stops) or ``drive`` (it drives on)."""
    silent_hold_s: float | None
    """How long after its last stamp a robot gone quiet holds still at the latest (:func:`silent_hold_s`);
    None under ``drive``. The safety filter's ``GuardConfig.silent_hold_s``."""
    holds: bool
    """Whether this robot's runtime holds it still when it is cut off: ``hold``, its controller
    does not handle that itself, and the others' safety filters can keep the hold (they keep a
    robot gone quiet as held only while the hold is younger than ``safety.max_age_s``; with a
    slower network they forget it, and a hold would only cost coordination)."""
    handled_by_controller: frozenset[str]
    """The other robots whose controllers handle being cut off themselves (the safety filter
    keeps them as any other robot when silent). Read only with ``[safety]`` on: a robot
    process imports no other robot's controller for nothing."""

    @classmethod
    def for_robot(cls, scenario: Scenario, name: str, handles_cut_off: Callable[[Scenario, str], bool]) -> "CutOffRule":
        """Robot ``name``'s rule; ``handles_cut_off(scenario, robot)`` says whether a robot's
        controller handles being cut off itself (:func:`agent.runtime.handles_cut_off`)."""
        hold = scenario.run.cut_off == "hold"
        limit = silent_hold_s(scenario)
        return cls(
            mode=scenario.run.cut_off,
            silent_hold_s=limit if hold else None,
            holds=hold and not handles_cut_off(scenario, name) and limit <= scenario.safety.max_age_s,
            handled_by_controller=(frozenset(r for r in scenario.robot_names
                                             if r != name and handles_cut_off(scenario, r))
                                   if scenario.safety.enabled else frozenset()),
        )


class HoldStage:
    """Stage "hold": a robot cut off, which the rule holds, commands zero.

    Reads: whether the robot is cut off now (the liveness stage) and the controller's command.
    Writes: the command (zeros) and telemetry ``cut_off``. The controller has stepped all the
    same: its messages still go out, so the others hear it the moment its radio is back."""

    name = "hold"

    def __init__(self, rule: CutOffRule, command_size: int) -> None:
        self.rule = rule
        self.command_size = command_size

    def held(self, cut_off: bool) -> bool:
        """Whether a robot so cut off is held still."""
        return cut_off and self.rule.holds

    def apply(self, cut_off: bool, command: list[float], telemetry: dict) -> list[float]:
        """The command to go on with: zeros when held (telemetry says ``cut_off``)."""
        if not self.held(cut_off):
            return command
        telemetry["cut_off"] = True
        return [0.0] * self.command_size
