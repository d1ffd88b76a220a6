"""Controller registry: scenario ``controller.type`` -> builder ``(RobotContext) -> Controller``.

Builders are imported lazily so a robot process loads only its own controller (and
CasADi only when an MPC controller is used).
"""

from __future__ import annotations

import importlib

from copath.control import Controller, RobotContext

__all__ = ["CONTROLLERS", "build_controller"]

CONTROLLERS: dict[str, str] = {
    # Sec. 5.5: Lyapunov path following + second-order consensus (unicycles)
    "consensus": "agent.controllers.consensus:build",
    # Sec. 4.2: omni NMPC path following / trajectory tracking
    "omni_nmpc_pf": "agent.controllers.omni_nmpc:build_path_following",
    "omni_nmpc_tt": "agent.controllers.omni_nmpc:build_trajectory_tracking",
    # Sec. 4.3: LTV-MPC QP with a velocity profile
    "ltv_mpc": "agent.controllers.ltv_mpc:build",
    # Sec. 4.4: unicycle NMPC blending path following and trajectory tracking
    "unicycle_nmpc": "agent.controllers.unicycle_nmpc:build",
    # Sec. 5.3: leader-following NMPC
    "leader_nmpc": "agent.controllers.leader_following:build_leader",
    "follower_nmpc": "agent.controllers.leader_following:build_follower",
    # Sec. 5.4: distributed MPC (with morphing for several paths)
    "dmpc": "agent.controllers.dmpc:build",
    # Sec. 5.5.5: heterogeneous team
    "hetero_leader": "agent.controllers.heterogeneous:build_leader",
    "hetero_follower": "agent.controllers.heterogeneous:build_follower",
    # Ch. 6: role assignment and formation switching; E6.6 switching on a path
    "roles": "agent.controllers.roles:build",
    "formation_switching": "agent.controllers.formation_switching:build",
}


def build_controller(kind: str, ctx: RobotContext) -> Controller:
    """Build the controller registered as ``kind`` for robot ``ctx``."""
    if kind not in CONTROLLERS:
        raise ValueError(f"controller type = {kind!r} is not allowed; choose one of {sorted(CONTROLLERS)}")
    module, func = CONTROLLERS[kind].split(":")
    return getattr(importlib.import_module(module), func)(ctx)
