"""Stage "estimate": the pose the robot believes, from its sensors (docs/reference/sensing.md,
"The estimator"; the dissertation's unicycles were located by a camera over the workplace and
a Kalman filter, Sec. 3.2.2 and Fig. 3.8)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from copath.estimation import PoseEKF
from copath.paths import wrap_to_pi
from copath.scenario import Scenario
from copath.wire.messages import Estimate, Obs

__all__ = ["EstimateStage"]


class EstimateStage:
    """One robot's pose estimate under ``[sensing]``.

    Reads: the observation's measurements (``Obs.meas``), the step's time, the previous
    step's command (solve-time compensation).
    Writes: the pose the later stages use, and an :class:`~copath.wire.messages.Estimate`
    record (with the estimator on).

    Without ``[sensing]`` (no measurements in the observation) it is not asked: the robot
    uses the simulator's pose."""

    name = "estimate"

    def __init__(self, scenario: Scenario, name: str) -> None:
        spec = scenario.robot(name)
        self.config = scenario.sensing
        self.profile = scenario.sensing.profile_for(name, spec.model.kind)
        self.kind = spec.model.kind
        self.ekf: PoseEKF | None = None
        """The estimator, built at the first measured observation (estimator on)."""
        self._raw_pose: np.ndarray | None = None

    @property
    def position_cov(self) -> list[float] | None:
        """[Pxx, Pxy, Pyy] of the position estimate, sent in the envelopes (None without the EKF)."""
        return None if self.ekf is None else self.ekf.position_cov

    def pose(self, obs: Obs, now: float, raw: np.ndarray,
             last_command: Sequence[float]) -> tuple[np.ndarray, Estimate | None]:
        """The pose the controller sees: the EKF's estimate at the observation's time,
        predicted to ``now`` plus ``solve_time_s`` with the last command (solve-time
        compensation); without the estimator, the raw reading with its heading unwrapped."""
        cfg = self.config
        if not cfg.estimator:
            if self._raw_pose is not None:
                raw = raw.copy()
                raw[2] = self._raw_pose[2] + wrap_to_pi(raw[2] - self._raw_pose[2])
            self._raw_pose = raw
            return raw, None
        if self.ekf is None:
            self.ekf = PoseEKF(self.profile, self.kind, cfg.filter, obs.t, raw)
        m = obs.meas
        res = self.ekf.step(obs.t, m.get("odom", ()), m.get("fixes", ()), m.get("headings", ()))
        ahead = (now - obs.t) + cfg.solve_time_s
        pose = self.ekf.predict_ahead(ahead, last_command) if ahead > 0 else res.pose.copy()
        rec = Estimate(obs.k, float(obs.t), [float(v) for v in res.x], res.P.tolist(), [float(v) for v in res.nis],
                       [int(v) for v in res.nis_dof],
                       {"accepted": res.accepted, "rejected": res.rejected, "late": res.late})
        return pose, rec
