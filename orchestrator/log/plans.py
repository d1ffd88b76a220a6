"""Broadcast plans read back from a run's records: the predicted horizon a controller sends
its neighbours, as positions on its path. One definition for the Foxglove views
(``orchestrator/view/foxglove.py``) and the ROS 2 export (``orchestrator/log/export.py``)."""

from __future__ import annotations

import numpy as np

from copath.paths import Path
from copath.wire.messages import PeerEnvelope

__all__ = ["plan_positions"]


def plan_positions(path: Path | None, env: PeerEnvelope) -> np.ndarray | None:
    """Predicted horizon of a broadcast plan as (N, 2) positions on the sender's ``path``
    (None: no path, or a record that carries no plan)."""
    if path is None:
        return None
    p = env.payload
    if env.kind == "assumed_traj":  # Algorithm 5.1 step 2: s_hat on the grid t0 + k dt
        s = np.asarray(p["s_hat"], dtype=float)
    elif env.kind == "leader_plan":  # Sec. 5.3: s_l and the planned speeds, step delta_l
        sd = np.asarray(p["sdot_pred"], dtype=float)
        s = float(p["s_l"]) + np.concatenate([[0.0], np.cumsum(sd) * float(p["delta_l"])])
    else:
        return None
    return path.pos(path.wrap(s) if path.closed else s)
