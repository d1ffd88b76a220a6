"""Sensing configuration and the robot's pose estimator (pure: no clock, no transport).

The dissertation's robots never knew their true pose. The omnidirectional robots of
Ch. 3-5 localised themselves with an omnidirectional camera and Monte-Carlo localisation
(Sec. 3.1, Fig. 3.1); the c't-Bot unicycles were tracked by an overhead camera (colour
segmentation and a Kalman filter) and measured their heading with a compass (Sec. 3.2,
Figs. 3.7-3.8). Sec. 5.5.4 names sensor distortion, vision-system delay and
communication delay as the main disturbances of the experiments.

This module holds

- :class:`SensorProfile`: one robot's sensors (position fixes, heading sensor, wheel
  odometry), shared by the simulator's sensor models (``sim/sensing.py``) and by the
  estimator's noise model (a robot knows the specification of its own sensors);
- :class:`SensingConfig`: the scenario's ``[sensing]`` table (a profile per robot, the
  estimator on or off, its tuning);
- :class:`PoseEKF`: an extended Kalman filter on the robot's kinematic model (3.1)/(3.3)
  with state (x, y, theta, b), b the heading sensor's bias. Odometry drives the
  prediction; delayed position and heading measurements are fused at the time they were
  taken by re-propagating the odometry from that time; a chi-square gate rejects outliers.

The chosen values of the ``realistic`` profiles and the derivation of the filter are in
docs/reference/sensing.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any, Mapping, Sequence

import numpy as np

from .config import ConfigError, from_table, require
from .models import integrate_body_velocity
from .paths import wrap_to_pi

__all__ = [
    "SensorProfile",
    "SensingConfig",
    "EstimatorConfig",
    "PoseEKF",
    "EstimateResult",
    "BUILTIN_PROFILES",
    "parse_sensing",
    "body_velocity",
]


def body_velocity(kind: str, cmd: Sequence[float]) -> tuple[float, float, float]:
    """Body velocities (u, v, omega) of a command: omni (u, v, omega), unicycle (v, omega)."""
    if kind == "unicycle":
        return float(cmd[0]), 0.0, float(cmd[1])
    return float(cmd[0]), float(cmd[1]), float(cmd[2])


@dataclass(frozen=True)
class SensorProfile:
    """One robot's sensors. With every noise, latency, bias and outlier term at zero the
    robot receives its true pose every tick, as without a ``[sensing]`` table."""

    fix_rate_hz: float = 25.0
    """Rate of position fixes (camera localisation) [Hz]."""
    fix_std_m: float = 0.0
    """Gaussian noise of each fix coordinate [m]."""
    fix_latency_s: float = 0.0
    """Time from taking a fix to its arrival at the robot (vision + network delay) [s]."""
    outlier_prob: float = 0.0
    """Probability that a fix is an outlier (mis-segmentation, a wrong MCL mode)."""
    outlier_std_m: float = 0.5
    """Gaussian spread of an outlier around the true position [m]."""
    heading_rate_hz: float = 25.0
    """Rate of heading measurements (compass, or the localisation's heading) [Hz]."""
    heading_std_rad: float = 0.0
    """Gaussian noise of each heading measurement [rad]."""
    heading_latency_s: float = 0.0
    """Time from taking a heading measurement to its arrival [s]."""
    heading_bias_rad: float = 0.0
    """Bias of the heading sensor at t = 0 [rad] (the estimator does not know it)."""
    heading_bias_walk: float = 0.0
    """Random-walk intensity of the heading bias [rad/sqrt(s)]."""
    odom_slip: float = 0.0
    """Relative standard deviation of the wheel odometry's velocities (slip)."""
    odom_std: float = 0.0
    """Absolute standard deviation of the odometry's velocities [m/s, rad/s]."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            require(math.isfinite(v) and v >= 0, f"sensing.{f.name}", v, "must be a finite number >= 0")
        require(self.fix_rate_hz > 0, "sensing.fix_rate_hz", self.fix_rate_hz, "must be > 0")
        require(self.heading_rate_hz > 0, "sensing.heading_rate_hz", self.heading_rate_hz, "must be > 0")
        require(self.outlier_prob <= 1, "sensing.outlier_prob", self.outlier_prob, "must be a probability in [0, 1]")

    @property
    def ideal(self) -> bool:
        """True when every term is zero: the robot sees its true pose every tick."""
        return all(getattr(self, f.name) == 0 for f in fields(self)
                   if f.name not in ("fix_rate_hz", "heading_rate_hz", "outlier_std_m"))


# chosen: values and reasoning in docs/reference/sensing.md ("The realistic profiles")
BUILTIN_PROFILES: dict[str, SensorProfile] = {
    "ideal": SensorProfile(),
    # omnidirectional robots: omnidirectional camera + Monte-Carlo localisation (Sec. 3.1)
    "realistic-omni": SensorProfile(
        fix_rate_hz=25.0, fix_std_m=0.03, fix_latency_s=0.08, outlier_prob=0.02, outlier_std_m=0.5,
        heading_rate_hz=25.0, heading_std_rad=0.03, heading_latency_s=0.08,
        heading_bias_rad=0.0, heading_bias_walk=0.0, odom_slip=0.05, odom_std=0.01,
    ),
    # c't-Bot unicycles: overhead camera + colour segmentation + Kalman filter, CMPS03 compass (Sec. 3.2)
    "realistic-unicycle": SensorProfile(
        fix_rate_hz=25.0, fix_std_m=0.02, fix_latency_s=0.12, outlier_prob=0.02, outlier_std_m=0.3,
        heading_rate_hz=10.0, heading_std_rad=0.05, heading_latency_s=0.05,
        heading_bias_rad=0.05, heading_bias_walk=0.005, odom_slip=0.05, odom_std=0.01,
    ),
}
"""Built-in profiles; ``realistic`` resolves to ``realistic-omni`` or ``realistic-unicycle``
by the robot's model."""

_PROFILE_KEYS = {f.name for f in fields(SensorProfile)}


@dataclass(frozen=True)
class EstimatorConfig:
    """Tuning of :class:`PoseEKF` beyond the sensor profile."""

    gate_prob: float = 0.999
    """Chi-square gate: a measurement whose normalised innovation squared exceeds this
    quantile of chi2(dof) is rejected as an outlier."""
    max_delay_s: float = 0.5
    """Re-propagation window: measurements taken longer ago than this are dropped as late [s]."""
    odom_std_min: float = 0.005
    """Floor of the odometry noise in the prediction [m/s, rad/s] (model error)."""
    bias_std0_rad: float = 0.1
    """Prior standard deviation of the heading bias [rad]."""
    bias_walk_min: float = 1e-4
    """Floor of the bias random walk in the prediction [rad/sqrt(s)]."""

    def __post_init__(self) -> None:
        require(0.5 < self.gate_prob < 1.0, "sensing.gate_prob", self.gate_prob, "must be in (0.5, 1)")
        require(self.max_delay_s > 0, "sensing.max_delay_s", self.max_delay_s, "must be > 0")
        require(self.odom_std_min > 0, "sensing.odom_std_min", self.odom_std_min, "must be > 0")
        require(self.bias_std0_rad > 0, "sensing.bias_std0_rad", self.bias_std0_rad, "must be > 0")
        require(self.bias_walk_min > 0, "sensing.bias_walk_min", self.bias_walk_min, "must be > 0")


@dataclass(frozen=True)
class _SensingTable:
    """The flat keys of ``[sensing]`` (validated by :func:`copath.config.from_table`)."""

    profile: str = "ideal"
    """Sensor profile of every robot: ``ideal`` (the true pose every tick), ``realistic``
    or a name under ``[sensing.profiles]`` (docs/reference/sensing.md)."""
    estimator: bool = True
    """Run the pose EKF in every robot with a non-ideal profile; false: the controller sees
    the latest raw reading."""
    solve_time_s: float = 0.0
    """Solve-time compensation: the controller sees the estimate predicted this far ahead [s] (0: off)."""


@dataclass(frozen=True)
class SensingConfig:
    """The scenario's ``[sensing]`` table::

        [sensing]
        profile = "realistic"          # default of every robot: ideal | realistic | a name below
        estimator = true               # an EKF in every robot (false: the latest raw reading)
        solve_time_s = 0.0             # solve-time compensation: predict this far ahead
        robots = { r2 = "ideal" }      # per-robot profile
        gate_prob = 0.999              # and the other EstimatorConfig keys (filter tuning)
        [sensing.profiles.noisy]       # a custom profile: SensorProfile keys,
        base = "realistic-unicycle"    # starting from a built-in profile (default "ideal")
        fix_std_m = 0.05
    """

    profile: str = "ideal"
    robots: Mapping[str, str] = field(default_factory=dict)
    profiles: Mapping[str, SensorProfile] = field(default_factory=dict)
    estimator: bool = True
    """Run :class:`PoseEKF` in every robot with a non-ideal profile; false: the controller
    sees the latest raw reading (fix position, heading measurement) held between arrivals."""
    solve_time_s: float = 0.0
    """Solve-time compensation: the controller sees the estimate predicted this far ahead
    with the last command [s] (0: off)."""
    filter: EstimatorConfig = field(default_factory=EstimatorConfig)

    def __post_init__(self) -> None:
        require(self.solve_time_s >= 0, "sensing.solve_time_s", self.solve_time_s, "must be >= 0")

    def profile_for(self, robot: str, kind: str) -> SensorProfile:
        """The sensor profile of ``robot`` whose model is ``kind`` (omni or unicycle)."""
        name = self.robots.get(robot, self.profile)
        return _resolve(name, kind, self.profiles, f"sensing.robots.{robot}" if robot in self.robots else "sensing.profile")

    @property
    def enabled(self) -> bool:
        return bool(self.robots) or self.profile != "ideal"


def _resolve(name: str, kind: str, custom: Mapping[str, SensorProfile], key: str) -> SensorProfile:
    if name in custom:
        return custom[name]
    if name == "realistic":
        name = f"realistic-{kind}"
    if name in BUILTIN_PROFILES:
        return BUILTIN_PROFILES[name]
    allowed = sorted({"realistic", *BUILTIN_PROFILES, *custom})
    raise ConfigError(f"{key} = {name!r} is not allowed; profiles: {', '.join(allowed)}")


def parse_sensing(table: Mapping[str, Any] | None, robot_names: Sequence[str] = ()) -> SensingConfig:
    """Validate the ``[sensing]`` table; errors name the key, the value and what is allowed."""
    table = dict(table or {})
    robots = table.pop("robots", {}) or {}
    profiles_raw = table.pop("profiles", {}) or {}
    require(isinstance(robots, dict), "sensing.robots", robots, "expected a table robot = \"profile\"")
    require(isinstance(profiles_raw, dict), "sensing.profiles", profiles_raw, "expected tables [sensing.profiles.NAME]")
    filter_keys = {f.name for f in fields(EstimatorConfig)}
    allowed = filter_keys | {f.name for f in fields(_SensingTable)} | {"robots", "profiles"}
    for k, v in table.items():
        require(k in allowed, f"sensing.{k}", v, f"allowed keys: {', '.join(sorted(allowed))}")
    flat = from_table(_SensingTable, {k: v for k, v in table.items() if k not in filter_keys}, "sensing")
    filt = from_table(EstimatorConfig, {k: v for k, v in table.items() if k in filter_keys}, "sensing")
    profiles: dict[str, SensorProfile] = {}
    for pname, ptab in profiles_raw.items():
        require(isinstance(ptab, dict), f"sensing.profiles.{pname}", ptab, "expected a table of sensor keys")
        require(pname not in BUILTIN_PROFILES and pname != "realistic", f"sensing.profiles.{pname}", pname,
                "a custom profile may not take a built-in name (" + ", ".join(sorted(BUILTIN_PROFILES)) + ")")
        ptab = dict(ptab)
        base = ptab.pop("base", "ideal")
        require(base in BUILTIN_PROFILES, f"sensing.profiles.{pname}.base", base,
                f"allowed: {', '.join(sorted(BUILTIN_PROFILES))}")
        try:
            over = from_table(SensorProfile, ptab, f"sensing.profiles.{pname}")
        except ConfigError as exc:  # SensorProfile names its keys sensing.<key>: say which profile
            msg = str(exc)
            raise ConfigError(msg if msg.startswith("sensing.profiles.") else
                              msg.replace("sensing.", f"sensing.profiles.{pname}.", 1)) from None
        profiles[pname] = replace(BUILTIN_PROFILES[base], **{k: getattr(over, k) for k in ptab})
    for r, p in robots.items():
        require(not robot_names or r in robot_names, f"sensing.robots.{r}", p, "must name a robot of this scenario")
        require(isinstance(p, str), f"sensing.robots.{r}", p, "expected a profile name")
    cfg = SensingConfig(flat.profile, dict(robots), profiles, flat.estimator, flat.solve_time_s, filt)
    for kind in ("omni", "unicycle"):  # every name resolves
        cfg.profile_for("", kind)
        for r in robots:
            cfg.profile_for(r, kind)
    return cfg


@dataclass
class EstimateResult:
    """The estimator's output at a control instant."""

    t: float
    x: np.ndarray
    """(4,) x, y, theta [m, m, rad] and heading-sensor bias b [rad]."""
    P: np.ndarray
    """(4, 4) covariance."""
    nis: list[float]
    """Normalised innovation squared of each measurement fused (or gated) for the first time."""
    nis_dof: list[int]
    """Degrees of freedom of each entry of ``nis`` (2: position fix, 1: heading)."""
    accepted: int
    """Measurements accepted so far."""
    rejected: int
    """Measurements rejected by the gate so far."""
    late: int
    """Measurements that arrived after the re-propagation window so far."""

    @property
    def pose(self) -> np.ndarray:
        return self.x[:3]


@dataclass
class _Meas:
    t: float
    kind: str  # "fix" or "heading"
    z: np.ndarray
    verdict: bool | None = None  # gate decision, taken once (the first time it is fused)


_H_FIX = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0]])
_H_HEAD = np.array([[0, 0, 1.0, 1.0]])


class PoseEKF:
    """EKF on the kinematic model (3.1) (omni) or (3.3) (unicycle, lateral velocity 0).

    State (x, y, theta, b). Prediction over an odometry segment [t0, t1] with measured
    body velocities (u, v, omega) uses the closed-form integration of (3.1) for the mean
    and the midpoint-heading Jacobians for the covariance; the odometry noise is
    ``odom_slip * |u_i| + odom_std`` per component and b follows a random walk.
    Measurements: a position fix z = (x, y) + n and a heading z = theta + b + n.

    Delays: the filter keeps an anchor (the estimate at time t_a with everything taken
    before t_a fused), the odometry segments after t_a and the measurements taken after
    t_a. Each step replays that window in time order, so a measurement taken at t_m and
    received later is fused exactly where an undelayed one would have been (a
    fixed-lag re-propagation, docs/reference/sensing.md). The anchor then moves to the newest
    segment boundary older than the sensors' latency (at most ``max_delay_s``): anything
    taken before it has already arrived.
    """

    def __init__(self, profile: SensorProfile, kind: str, cfg: EstimatorConfig, t0: float, pose0: Sequence[float]) -> None:
        self.profile = profile
        self.kind = kind
        self.cfg = cfg
        self.R_fix = np.eye(2) * max(profile.fix_std_m, 1e-4) ** 2
        self.R_head = np.array([[max(profile.heading_std_rad, 1e-4) ** 2]])
        self.q_bias = max(profile.heading_bias_walk, cfg.bias_walk_min) ** 2
        sb = max(cfg.bias_std0_rad, abs(profile.heading_bias_rad))
        sf = max(profile.fix_std_m, 1e-3)
        sh = max(profile.heading_std_rad, 1e-3)
        # pose0 is a raw reading: theta0 = theta + b + n, so theta and b start anti-correlated
        P0 = np.diag([sf**2, sf**2, sh**2 + sb**2, sb**2])
        P0[2, 3] = P0[3, 2] = -(sb**2)
        x0 = np.array([float(pose0[0]), float(pose0[1]), float(pose0[2]), 0.0])
        self._anchor = (float(t0), x0, P0)
        self._segments: list[tuple[float, float, np.ndarray]] = []
        self._meas: list[_Meas] = []
        from scipy.stats import chi2  # noqa: PLC0415  (0.9 s to import: only robots with an EKF pay it)

        self._gate = {d: float(chi2.ppf(cfg.gate_prob, d)) for d in (1, 2)}
        self.t = float(t0)
        self.x = x0.copy()
        self.P = P0.copy()
        self.accepted = 0
        self.rejected = 0
        self.late = 0
        self._last_stamp = {"fix": -math.inf, "heading": -math.inf}

    # -- model ---------------------------------------------------------------------------
    def _predict(self, x: np.ndarray, P: np.ndarray, u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt <= 0:
            return x, P
        ub, vb, w = u
        nx = integrate_body_velocity(x[:3], u, dt)
        dx, dy = nx[0] - x[0], nx[1] - x[1]
        thm = x[2] + 0.5 * w * dt
        c, s = math.cos(thm), math.sin(thm)
        F = np.eye(4)
        F[0, 2], F[1, 2] = -dy, dx
        G = np.array([[dt * c, -dt * s, -0.5 * dt * dy],
                      [dt * s, dt * c, 0.5 * dt * dx],
                      [0.0, 0.0, dt],
                      [0.0, 0.0, 0.0]])
        p = self.profile
        sig = p.odom_slip * np.abs(u) + max(p.odom_std, self.cfg.odom_std_min)
        if self.kind == "unicycle":  # no lateral velocity: only a small side slip
            sig[1] = max(p.odom_std, self.cfg.odom_std_min)
        P = F @ P @ F.T + (G * sig**2) @ G.T
        P[3, 3] += self.q_bias * dt
        return np.array([nx[0], nx[1], nx[2], x[3]]), P

    def _update(self, x: np.ndarray, P: np.ndarray, m: _Meas) -> tuple[np.ndarray, np.ndarray, float, int]:
        if m.kind == "fix":
            H, R = _H_FIX, self.R_fix
            nu = m.z - x[:2]
        else:
            H, R = _H_HEAD, self.R_head
            nu = np.array([wrap_to_pi(float(m.z[0]) - x[2] - x[3])])
        S = H @ P @ H.T + R
        Si = np.linalg.inv(S)
        d2 = float(nu @ Si @ nu)
        dof = len(nu)
        if m.verdict is None:
            m.verdict = d2 <= self._gate[dof]
            if m.verdict:
                self.accepted += 1
            else:
                self.rejected += 1
            self._new_nis.append((d2, dof))
        if not m.verdict:
            return x, P, d2, dof
        K = P @ H.T @ Si
        x = x + K @ nu
        IKH = np.eye(4) - K @ H
        P = IKH @ P @ IKH.T + K @ R @ K.T  # Joseph form
        return x, P, d2, dof

    # -- public --------------------------------------------------------------------------
    def step(
        self,
        t: float,
        odometry: Sequence[Sequence[float]] = (),
        fixes: Sequence[Sequence[float]] = (),
        headings: Sequence[Sequence[float]] = (),
    ) -> EstimateResult:
        """Fuse what arrived by controller time ``t`` and return the estimate at ``t``.

        ``odometry``: segments ``[t0, t1, u, v, omega]`` (measured body velocities held
        over [t0, t1]); ``fixes``: ``[t_taken, x, y]``; ``headings``: ``[t_taken, theta]``.
        Segments and measurements already seen (by their times) are ignored, so the
        same observation may be given twice.
        """
        t_a = self._anchor[0]
        end = self._segments[-1][1] if self._segments else t_a
        for seg in odometry:
            t0, t1 = float(seg[0]), float(seg[1])
            if t1 <= end + 1e-9:
                continue
            if t0 > end + 1e-9:  # a gap: hold still over it (no odometry means no motion known)
                self._segments.append((end, t0, np.zeros(3)))
            self._segments.append((max(t0, end), t1, np.array(body_velocity(self.kind, seg[2:]), dtype=float)))
            end = t1
        if t > end + 1e-9:  # no odometry up to t: predict with zero velocity
            self._segments.append((end, float(t), np.zeros(3)))
        for kind, items in (("fix", fixes), ("heading", headings)):
            for m in items:
                tm = float(m[0])
                if tm <= self._last_stamp[kind]:
                    continue
                self._last_stamp[kind] = tm
                if tm < t_a - 1e-12:
                    self.late += 1
                    continue
                self._meas.append(_Meas(tm, kind, np.array(m[1:], dtype=float)))
        self._meas.sort(key=lambda m: (m.t, m.kind))
        self._new_nis: list[tuple[float, int]] = []
        self._replay(float(t))
        return EstimateResult(self.t, self.x.copy(), self.P.copy(), [d for d, _ in self._new_nis],
                              [k for _, k in self._new_nis], self.accepted, self.rejected, self.late)

    def _replay(self, t: float) -> None:
        t_a, x, P = self._anchor
        # everything taken before t - (sensor latency) has arrived: the window need not reach further back
        latency = max(self.profile.fix_latency_s, self.profile.heading_latency_s)
        cut = t - min(self.cfg.max_delay_s, latency + 1e-6)
        new_anchor = None
        cur = t_a
        mi = 0
        meas = self._meas
        for si, (t0, t1, u) in enumerate(self._segments):
            while mi < len(meas) and meas[mi].t <= t1 + 1e-12:
                x, P = self._predict(x, P, u, meas[mi].t - cur)
                cur = max(cur, meas[mi].t)
                x, P, _, _ = self._update(x, P, meas[mi])
                mi += 1
            x, P = self._predict(x, P, u, t1 - cur)
            cur = t1
            if t1 <= cut:
                new_anchor = (si, mi, (t1, x.copy(), P.copy()))
        while mi < len(meas):  # taken after the last odometry (should not happen)
            x, P, _, _ = self._update(x, P, meas[mi])
            mi += 1
        if new_anchor is not None:
            si, mj, anchor = new_anchor
            self._anchor = anchor
            self._segments = self._segments[si + 1 :]
            self._meas = meas[mj:]
        self.t, self.x, self.P = t, x, P

    def predict_ahead(self, dt: float, cmd: Sequence[float]) -> np.ndarray:
        """The pose ``dt`` ahead of the current estimate under command ``cmd`` (solve-time
        compensation: the state when the command being computed will be applied)."""
        if dt <= 0:
            return self.x[:3].copy()
        return integrate_body_velocity(self.x[:3], body_velocity(self.kind, cmd), dt)

    @property
    def position_cov(self) -> list[float]:
        """[Pxx, Pxy, Pyy] of the position estimate (shared with neighbours)."""
        return [float(self.P[0, 0]), float(self.P[0, 1]), float(self.P[1, 1])]
