"""The stages of one robot's control instant, in the order :class:`agent.runtime.RobotRuntime`
runs them (docs/reference/faults.md, safety.md, detours.md, sensing.md).

Each stage is a small object that owns its state and says what it reads and what it
writes; the runtime is the pipeline that feeds one stage's output to the next:

========== ========================================= =============================================
stage      module                                     does
========== ========================================= =============================================
trust      :mod:`agent.stages.trust`                  stamp window, rejects, messages before the first step
estimate   :mod:`agent.stages.estimate`               the pose the robot believes (``[sensing]``)
faults     :mod:`agent.stages.faults`                 fault layer release, lost senders, range filter (Def. 10)
liveness   :mod:`agent.stages.liveness`               tokens, silence, cut off (the cut-off rule's detection)
detour     :mod:`agent.stages.detour`                 the lane shifted round a blocked stretch
control    :mod:`agent.stages.control`                the controller's step, its failures contained
hold       :mod:`agent.stages.cut_off`                a cut-off robot commands zero (the cut-off rule's action)
safety     :mod:`agent.stages.safety`                 the decentralised safety filter, fed by overhearing
envelopes  :mod:`agent.stages.envelopes`              the applied command and the outgoing peer envelopes
========== ========================================= =============================================

Two stages act outside the instant as well: trust and faults take each envelope as it
arrives (:meth:`agent.runtime.RobotRuntime.receive`), safety each overheard one.
"""

from __future__ import annotations

from .control import ControlResult, ControlStage
from .counters import Counters
from .cut_off import CutOffRule, HoldStage
from .detour import DetourStage
from .envelopes import EnvelopeStage
from .estimate import EstimateStage
from .faults import FaultStage, Released
from .liveness import Liveness, LivenessStage
from .safety import SafetyStage
from .trust import TrustStage

STAGE_ORDER = ("trust", "estimate", "faults", "liveness", "detour", "control", "hold", "safety", "envelopes")
"""The names of the stages of one control instant, in the order they run."""

__all__ = ["STAGE_ORDER", "ControlResult", "ControlStage", "Counters", "CutOffRule", "DetourStage", "EnvelopeStage",
           "EstimateStage", "FaultStage", "HoldStage", "Liveness", "LivenessStage", "Released", "SafetyStage",
           "TrustStage"]
