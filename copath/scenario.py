"""Scenario model: one validated object per ``configs/*.toml`` file.

The reference of every table and key (type, default, meaning) is docs/reference/scenarios.md,
generated from the dataclasses below (``python -m orchestrator.reference``).

The TOML layout (every table optional unless said)::

    id = "my-test"                   # free scenario name: letters, digits, "-", "_", "."
    experiment = "e5.5"              # optional: the dissertation experiment it reproduces
    title = "..."
    [run]       duration_s, dt, clock ("lockstep" | "realtime"), settle_s, seed,
                tick_timeout_s, rate_hz (realtime controller rate; default 1/dt),
                until, secure, on_robot_failure, watchdog_s, command_timeout_s, lease_s, liveliness_grace_s,
                cut_off ("hold" | "drive"; docs/reference/faults.md),
                kills = [{robot, at_s}] (a robot's process killed, as with SIGKILL)
    [network]   delay_ms, jitter_ms, loss, burst_p_gb, burst_p_bg, burst_loss,
                range_m (0 = fixed graph from robots.neighbours),
                partitions = [{links = [["r1", "r2"]], start_s, end_s}],
                silence = [{robot, start_s, end_s}]
    [noise]     pose_std = [sx, sy, stheta], range_std
    [sensors]   enabled, count, max_range_m
    [sensing]   profile, estimator, solve_time_s, robots = {r1 = "ideal"}, [sensing.profiles.NAME]
                (position fixes, compass, odometry and the robots' EKF: copath.estimation)
    [paths.NAME] type = "lemniscate" | "eight" | ... and the curve's keys (copath.paths)
    [controller] type = "<registered controller>" and its parameters (defaults for all)
    [[robots]]  name, model ("omni" | "unicycle" | table), pose = [x, y, theta], path,
                neighbours = [...], [robots.controller] per-robot overrides
    [[obstacles]] vertices = [[x, y], ...], velocity = [vx, vy] (optional), known (optional)
    [metrics]   coordination_pairs = "all" | "edges", formation_tolerance_m, task_tolerance_m
                (copath.metrics_config; docs/reference/metrics.md)
    [safety]    enabled, gamma, margin_m, speed_max_mps, overhear, ... (copath.safety)
    [targets]   metric key = threshold, e.g. coordination_error_max_m = 0.1 (copath.grading)
    [world]     backend ("sim" | "ros2"), start_timeout_s, pose_type, cmd_rate_hz,
                [world.robots.NAME] pose_topic, pose_type, cmd_topic, frame, origin
                (copath.ros2.config; docs/reference/ros2.md)

Controller parameters whose key ends in ``_file`` (a string) or ``_files`` (a list) are
data files relative to the scenario file; the loader replaces them by their content
(JSON, or CSV of ``x,y`` rows) under the key without the suffix.

Parsing from a file happens only in the entry points (orchestrator, agent/sim nodes);
:func:`parse_scenario` takes the already-read table.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import itertools
import json
import math
import pathlib
import re
import tomllib
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from .config import ConfigError, ConfigErrors, as_float_tuple, from_table, require
from .estimation import SensingConfig, parse_sensing
from .metrics_config import parse_metrics
from .models import OmniModel, UnicycleModel, make_model
from .paths import Path, make_path
from .ros2.config import WorldConfig, parse_world
from .safety import SafetyConfig
from .grading import Target, parse_targets

__all__ = [
    "Scenario",
    "RunConfig",
    "Kill",
    "kill_tick",
    "NetworkConfig",
    "NoiseConfig",
    "SensorConfig",
    "RobotSpec",
    "ObstacleSpec",
    "parse_scenario",
    "load_scenario",
    "key_lines",
    "locate_errors",
    "ConfigError",
    "ConfigErrors",
]

CLOCKS = ("lockstep", "realtime")
UNTILS = ("duration", "tasks_done")
FAILURE_POLICIES = ("fail", "continue", "restart")
CUT_OFF_RULES = ("hold", "drive")
_ID_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
_CONTROLLER_RE = re.compile(r"[A-Za-z_][\w.-]*|[A-Za-z_][\w.]*:[A-Za-z_]\w*")
_EXPERIMENT_RE = re.compile(r"e[4-6]\.[0-9]+")


@dataclass(frozen=True)
class Kill:
    """A robot's process killed during the run, as with SIGKILL (docs/reference/faults.md, "A
    kill declared in the scenario"): it answers no observation from the first at or after
    ``at_s`` on, its liveliness token goes, and ``run.on_robot_failure`` applies."""

    robot: str
    """The killed robot's name."""
    at_s: float
    """When [s] (> 0, simulated time)."""

    def due_s(self, dt: float) -> float:
        """The run time [s] the kill falls due: half a period after ``at_s``, so that the robot's
        step at ``at_s`` (on the tick grid) is its last."""
        return self.at_s + 0.5 * dt


def kill_tick(at_s: float, dt: float) -> int:
    """The first tick whose observation comes at or after a kill at ``at_s`` falls due
    (:meth:`Kill.due_s`): the one its process dies on over Zenoh and the one its teammates learn
    of the loss at (``Obs.down``); in one process its link closes just before it. The one place
    that says it, for the agent, the simulator and the one-process loop alike."""
    return math.ceil((at_s + 0.5 * dt) / dt - 1e-9)


@dataclass(frozen=True)
class RunConfig:
    duration_s: float = 60.0
    """Simulated duration [s]."""
    dt: float = 0.1
    """Control period and lockstep tick [s]."""
    clock: str = "lockstep"
    """``lockstep`` (deterministic) or ``realtime`` (wall clock, asynchronous agents)."""
    settle_s: float = 0.0
    """Errors in metrics.json are measured after this time [s]."""
    seed: int = 0
    """Seed of every random draw of the run (noise, faults, random starts)."""
    tick_timeout_s: float = 10.0
    """Lockstep: how long the simulator waits for a robot's command before counting a miss [s]."""
    physics_dt: float = 0.01
    """Realtime: integration step of the simulator [s]."""
    until: str = "duration"
    """``duration``: the run lasts ``duration_s``; ``tasks_done``: it ends ``until_margin_s``
    after the truth completes the last formation of the task queue (Chapter 6; the rule of
    docs/reference/metrics.md, tasks of Chapter 6 (M5), :mod:`copath.occupancy`), and at ``duration_s`` at the latest
    (docs/reference/performance.md, "Runs that end when their work is done")."""
    until_margin_s: float = 5.0
    """``until = "tasks_done"``: simulated time kept after the truth completed the last task [s]."""
    secure: bool = True
    """Per-run credentials and access control on the run's router (docs/reference/security.md): each
    robot may publish only under its own keys, only the simulator publishes observations
    and truth, and a session without the run's credentials can neither inject nor read.
    On by default (it costs 3-7 % of lockstep speed); ``false`` for a fleet whose robots
    reach the run through a router of their own, which logs in as nobody."""
    on_robot_failure: str = "fail"
    """What a robot process that dies or freezes (its liveliness lease expires) does to the
    run: ``fail`` ends it; ``continue`` stops that robot where it is and the others go on
    without it; ``restart`` starts its process again, which rejoins from the current
    world state (docs/reference/faults.md)."""
    watchdog_s: float = 5.0
    """An agent that hears nothing from the simulator for this long commands zero
    velocity and logs an event (0: off)."""
    command_timeout_s: float = 1.0
    """Realtime runs: a robot whose base has received no command for this long [s] stops (zero
    command, within its acceleration limits), as a real base's command timeout does; event
    ``command_timeout`` (0: off). An agent whose step hangs (a solver that takes seconds) keeps its
    liveliness, so nothing else stops its robot driving on its last command (docs/reference/faults.md,
    "A base stops on stale commands"). Lockstep runs wait for every command (``tick_timeout_s``)."""
    lease_s: float = 1.0
    """Zenoh transport lease of every process of the run and of its router [s]: a frozen
    process loses its liveliness within about this time. On a machine with far more
    processes than cores (about a hundred robots on two) a starved transport misses a 1 s
    lease and is reset; a longer lease avoids that (docs/journal/performance.md, realtime at 128 robots (P10))."""
    liveliness_grace_s: float = 5.0
    """A liveliness token that disappears counts as a lost process only when it has not come
    back within this time [s]: a transport reset under CPU starvation (the 1 s lease lapses,
    the client reconnects) is not a loss (docs/reference/faults.md). Under ``continue``/``restart`` the
    simulator holds the robot still at once and lets it rejoin, as before."""
    cut_off: str = "hold"
    """What a robot does once it has lost every other robot it has heard, at least one by
    radio silence: ``hold`` (default) stops it until it hears one again, and every safety
    filter keeps a silent robot as a static disc round where it may have stopped (it cannot
    be seen, nor coordinate); ``drive`` lets its controller drive on, blind, and the filters
    forget it after ``safety.max_age_s`` (docs/reference/faults.md, "Gone quiet"; docs/reference/safety.md).
    A robot's controller may handle being cut off itself (roles, docs/reference/ambiguities.md, robot lost in role assignment (A38))."""
    kills: tuple[Kill, ...] = ()
    """Robot processes killed during the run ``[{robot, at_s}]``, as with SIGKILL; a robot
    restarted under ``restart`` may be killed again at a later time (docs/reference/faults.md, "A
    kill declared in the scenario")."""

    def __post_init__(self) -> None:
        require(self.duration_s > 0, "run.duration_s", self.duration_s, "must be > 0")
        require(self.dt > 0, "run.dt", self.dt, "must be > 0")
        require(self.clock in CLOCKS, "run.clock", self.clock, f"allowed: {', '.join(CLOCKS)}")
        require(self.settle_s >= 0, "run.settle_s", self.settle_s, "must be >= 0")
        require(self.tick_timeout_s > 0, "run.tick_timeout_s", self.tick_timeout_s, "must be > 0")
        require(self.physics_dt > 0, "run.physics_dt", self.physics_dt, "must be > 0")
        require(self.until in UNTILS, "run.until", self.until, f"allowed: {', '.join(UNTILS)}")
        require(self.until_margin_s >= 0, "run.until_margin_s", self.until_margin_s, "must be >= 0")
        require(isinstance(self.secure, bool), "run.secure", self.secure, "must be true or false")
        require(self.on_robot_failure in FAILURE_POLICIES, "run.on_robot_failure", self.on_robot_failure,
                f"allowed: {', '.join(FAILURE_POLICIES)}")
        require(self.watchdog_s >= 0, "run.watchdog_s", self.watchdog_s, "must be >= 0 (0: off)")
        require(self.command_timeout_s >= 0, "run.command_timeout_s", self.command_timeout_s, "must be >= 0 (0: off)")
        require(self.lease_s > 0, "run.lease_s", self.lease_s, "must be > 0")
        require(self.liveliness_grace_s >= 0, "run.liveliness_grace_s", self.liveliness_grace_s, "must be >= 0")
        require(self.cut_off in CUT_OFF_RULES, "run.cut_off", self.cut_off, f"allowed: {', '.join(CUT_OFF_RULES)}")


@dataclass(frozen=True)
class Partition:
    """Named links cut over [start_s, end_s) (both directions of each link)."""

    links: tuple[tuple[str, str], ...]
    """Pairs of robots ``[["r1", "r2"], ...]``; each must be an edge of the fixed communication
    graph (``robots.neighbours``) unless ``network.range_m > 0``."""
    start_s: float = 0.0
    """Start of the cut [s]."""
    end_s: float = math.inf
    """End of the cut [s] (default: the end of the run)."""


@dataclass(frozen=True)
class Silence:
    """A robot whose radio is silent over [start_s, end_s): it neither sends nor receives
    robot-to-robot messages (its link to the simulator stays up)."""

    robot: str
    """The silent robot's name."""
    start_s: float = 0.0
    """Start of the silence [s]."""
    end_s: float = math.inf
    """End of the silence [s] (default: the end of the run)."""


@dataclass(frozen=True)
class NetworkConfig:
    delay_ms: float = 0.0
    """Fixed delay added to every robot-to-robot message [ms]."""
    jitter_ms: float = 0.0
    """Uniform extra delay in [0, jitter_ms] [ms]."""
    loss: float = 0.0
    """Bernoulli loss probability of a message."""
    burst_p_gb: float = 0.0
    """Gilbert-Elliott: probability good -> bad per message (0 disables burst loss)."""
    burst_p_bg: float = 0.5
    """Gilbert-Elliott: probability bad -> good per message."""
    burst_loss: float = 1.0
    """Loss probability in the bad state."""
    range_m: float = 0.0
    """Communication range r [m] (Def. 10); 0 means a fixed graph from robots.neighbours."""
    partitions: tuple[Partition, ...] = ()
    """Scheduled partitions ``[{links, start_s, end_s}]`` of named links (docs/reference/faults.md)."""
    silence: tuple[Silence, ...] = ()
    """Radio silences ``[{robot, start_s, end_s}]`` (docs/reference/faults.md)."""

    def __post_init__(self) -> None:
        require(self.delay_ms >= 0, "network.delay_ms", self.delay_ms, "must be >= 0")
        require(self.jitter_ms >= 0, "network.jitter_ms", self.jitter_ms, "must be >= 0")
        for k in ("loss", "burst_p_gb", "burst_p_bg", "burst_loss"):
            v = getattr(self, k)
            require(0.0 <= v <= 1.0, f"network.{k}", v, "must be a probability in [0, 1]")
        require(self.range_m >= 0, "network.range_m", self.range_m, "must be >= 0")


@dataclass(frozen=True)
class NoiseConfig:
    pose_std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Gaussian noise on the published pose estimate (x [m], y [m], theta [rad])."""
    range_std: float = 0.0
    """Gaussian noise on range readings [m]."""

    def __post_init__(self) -> None:
        require(all(s >= 0 for s in self.pose_std), "noise.pose_std", self.pose_std, "must be >= 0")
        require(self.range_std >= 0, "noise.range_std", self.range_std, "must be >= 0")


@dataclass(frozen=True)
class SensorConfig:
    enabled: bool = False
    """Publish a ring of range readings to each robot."""
    count: int = 12
    """Number of rays, evenly spaced from 0 deg (default 12: every 30 deg)."""
    max_range_m: float = 0.5
    """Range of each ray [m]."""

    def __post_init__(self) -> None:
        require(self.count >= 1, "sensors.count", self.count, "must be >= 1")
        require(self.max_range_m > 0, "sensors.max_range_m", self.max_range_m, "must be > 0")

    def angles(self):
        """Bearings of the rays [rad] in the body frame, from 0 counter-clockwise, evenly
        spaced (Sec. 4.4.2): ``2 pi k / count``."""
        import numpy as np  # noqa: PLC0415

        return 2 * math.pi * np.arange(self.count) / self.count


@dataclass(frozen=True)
class RobotSpec:
    name: str
    model: OmniModel | UnicycleModel
    pose: tuple[float, float, float]
    path: str | None
    neighbours: tuple[str, ...]
    controller: str
    params: Mapping[str, Any]


@dataclass(frozen=True)
class ObstacleSpec:
    vertices: tuple[tuple[float, float], ...]
    """Convex polygon at t = 0, counter-clockwise or clockwise [m]."""
    velocity: tuple[float, float] = (0.0, 0.0)
    """Constant translation velocity [m/s]."""
    known: bool = False
    """On the map every robot is given: robots plan detours round it from the start
    (docs/reference/detours.md); false: robots know of it only through their range sensors."""


@dataclass(frozen=True)
class Scenario:
    id: str
    """The scenario's name (free text: letters, digits, ``-_.``)."""
    experiment: str | None
    """The dissertation experiment it reproduces (e.g. ``"e5.5"``), or None."""
    title: str
    run: RunConfig
    network: NetworkConfig
    noise: NoiseConfig
    sensors: SensorConfig
    paths: Mapping[str, Path]
    robots: tuple[RobotSpec, ...]
    obstacles: tuple[ObstacleSpec, ...]
    metrics: Mapping[str, Any]
    raw: Mapping[str, Any] = field(repr=False)
    """The table the scenario was parsed from (recorded as MCAP metadata)."""
    source: str = ""
    """File name the scenario came from, if any."""
    sensing: SensingConfig = field(default_factory=SensingConfig)
    """Sensor profiles and the robots' estimator (``[sensing]``, copath.estimation)."""
    targets: tuple[Target, ...] = ()
    """Goals a run is graded against (``[targets]``, :func:`copath.grading.grade`)."""
    safety: SafetyConfig = SafetyConfig()
    """The per-robot safety filter (``[safety]``, :mod:`copath.safety`); off by default."""
    world: WorldConfig = WorldConfig()
    """Which world the robots live in (``[world]``, :mod:`copath.ros2.config`): copath's
    simulator (default) or ROS 2 robots (docs/reference/ros2.md)."""

    @property
    def robot_names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.robots)

    def in_column(self, name: str) -> bool:
        """Whether another robot follows the path robot ``name`` follows (its safety filter and
        its detours treat it as one of a column: docs/reference/safety.md, "Deadlock rule";
        docs/reference/detours.md, "Turn first")."""
        path = self.robot(name).path
        return path is not None and any(r.path == path for r in self.robots if r.name != name)

    def robot(self, name: str) -> RobotSpec:
        for r in self.robots:
            if r.name == name:
                return r
        raise ConfigError(f"robot = {name!r} is not in the scenario; robots: {', '.join(self.robot_names)}")

    def edges(self) -> list[tuple[str, str]]:
        """Undirected edges of the fixed communication graph."""
        out = set()
        for r in self.robots:
            for n in r.neighbours:
                out.add(tuple(sorted((r.name, n))))
        return sorted(out)

    def with_overrides(self, **sections: Mapping[str, Any]) -> "Scenario":
        """A copy with keys of top-level tables replaced, e.g. ``network={"delay_ms": 100}``."""
        raw = copy.deepcopy(dict(self.raw))
        for section, values in sections.items():
            raw.setdefault(section, {})
            raw[section].update(values)
        return parse_scenario(raw, base_dir=None, source=self.source)


_ROBOT_KEYS = frozenset({"name", "model", "pose", "path", "neighbours", "controller"})
_TOP_KEYS = {"_source", "id", "experiment", "title", "run", "network", "noise", "sensors", "paths", "controller", "robots",
             "obstacles", "metrics", "targets", "safety", "notes",
             "sensing", "world"}


def _load_data_file(base_dir: pathlib.Path | None, name: str, key: str) -> Any:
    if base_dir is None:
        raise ConfigError(f"{key} = {name!r} cannot be resolved without the scenario's directory")
    path = (base_dir / name).resolve()
    if not path.is_file():
        raise ConfigError(f"{key} = {name!r} is not allowed; no such file next to the scenario")
    if path.suffix == ".json":
        return json.loads(path.read_text())
    if path.suffix == ".csv":
        rows = []
        with path.open() as fh:
            for row in csv.reader(fh):
                if not row or row[0].strip().startswith("#") or not row[0].strip():
                    continue
                try:
                    rows.append([float(v) for v in row])
                except ValueError:
                    if rows:  # only the first row may be a header
                        raise ConfigError(f"{key}: {name} has a non-numeric row {row!r}") from None
        return rows
    raise ConfigError(f"{key} = {name!r} is not allowed; data files must be .json or .csv")


def _resolve_files(params: dict, base_dir: pathlib.Path | None, where: str) -> dict:
    out = {}
    for k, v in params.items():
        if k.endswith("_files"):
            require(isinstance(v, list), f"{where}.{k}", v, "expected a list of file names")
            out[k[: -len("_files")]] = [_load_data_file(base_dir, f, f"{where}.{k}") for f in v]
        elif k.endswith("_file"):
            out[k[: -len("_file")]] = _load_data_file(base_dir, v, f"{where}.{k}")
        else:
            out[k] = v
    return out


class _Errors:
    """Collects every ConfigError of a scenario so that all are reported at once."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def take(self, fn: Callable[[], Any], default: Any = None) -> Any:
        """``fn()``, or ``default`` after recording its ConfigError(s)."""
        try:
            return fn()
        except ConfigErrors as exc:
            self.items.extend(exc.errors)
        except ConfigError as exc:
            self.items.append(str(exc))
        return default

    def check(self, cond: bool, key: str, value: Any, allowed: str) -> bool:
        """:func:`copath.config.require`, recorded instead of raised; returns ``cond``."""
        return self.take(lambda: require(cond, key, value, allowed) or True, False)


def _sub_error(prefix: str, exc: Exception) -> ConfigError:
    """``prefix.key = value ...`` when the message starts with a key, else ``prefix: message``."""
    msg = str(exc)
    head = msg.split(" = ", 1)[0]
    if " = " in msg and head.replace("_", "").replace(".", "").isalnum():
        return ConfigError(f"{prefix}.{msg}")
    return ConfigError(f"{prefix}: {msg}")


def _partition(p: Any, where: str) -> Partition:
    require(isinstance(p, dict), where, p, "expected a table {links, start_s, end_s}")
    links = p.get("links")
    require(isinstance(links, list) and all(isinstance(l, list) and len(l) == 2 for l in links),
            f"{where}.links", links, "expected a list of [robot, robot] pairs")
    start, end = float(p.get("start_s", 0.0)), float(p.get("end_s", math.inf))
    require(end > start, f"{where}.end_s", end, "must be greater than start_s")
    return Partition(tuple((str(a), str(b)) for a, b in links), start, end)


def _silence(p: Any, where: str) -> Silence:
    require(isinstance(p, dict), where, p, "expected a table {robot, start_s, end_s}")
    for k in p:
        require(k in ("robot", "start_s", "end_s"), f"{where}.{k}", p[k], "allowed keys: robot, start_s, end_s")
    require(isinstance(p.get("robot"), str), f"{where}.robot", p.get("robot"), "expected a robot name")
    start, end = float(p.get("start_s", 0.0)), float(p.get("end_s", math.inf))
    require(end > start, f"{where}.end_s", end, "must be greater than start_s")
    return Silence(p["robot"], start, end)


def _kill(p: Any, where: str) -> Kill:
    require(isinstance(p, dict), where, p, "expected a table {robot, at_s}")
    for k in p:
        require(k in ("robot", "at_s"), f"{where}.{k}", p[k], "allowed keys: robot, at_s")
    require(isinstance(p.get("robot"), str), f"{where}.robot", p.get("robot"), "expected a robot name")
    at = p.get("at_s")
    require(isinstance(at, (int, float)) and not isinstance(at, bool) and math.isfinite(at) and at > 0,
            f"{where}.at_s", at, "expected a time [s] > 0")
    return Kill(p["robot"], float(at))


def _obstacle(o: Any, where: str) -> ObstacleSpec:
    require(isinstance(o, dict), where, o, "expected a table {vertices, velocity, known}")
    for k in o:
        require(k in ("vertices", "velocity", "known"), f"{where}.{k}", o[k], "allowed keys: vertices, velocity, known")
    verts = o.get("vertices")
    require(isinstance(verts, list) and len(verts) >= 3, f"{where}.vertices", verts, "expected >= 3 [x, y] points")
    vs = tuple(as_float_tuple(v, f"{where}.vertices[{j}]", 2) for j, v in enumerate(verts))
    vel = as_float_tuple(o.get("velocity", [0.0, 0.0]), f"{where}.velocity", 2)
    known = o.get("known", False)
    require(isinstance(known, bool), f"{where}.known", known, "expected true or false")
    return ObstacleSpec(vs, vel, known)


def _robot(r: Any, i: int, names: list, paths: Mapping[str, Path], defaults: dict, errs: _Errors,
           broken: frozenset[str] = frozenset()) -> RobotSpec | None:
    where = f"robots[{i}]"
    if not errs.check(isinstance(r, dict), where, r, "expected a table {name, model, pose, path, ...}"):
        return None
    for k in r:
        errs.check(k in _ROBOT_KEYS, f"{where}.{k}", r[k], f"allowed keys: {', '.join(sorted(_ROBOT_KEYS))}")
    name = r.get("name")
    if not errs.check(isinstance(name, str) and name.isidentifier(), f"{where}.name", name,
                      "expected an identifier such as 'r1' (letters, digits, underscore)"):
        return None
    if not errs.check(names.count(name) == 1, f"{where}.name", name, "robot names must be unique"):
        return None
    model = errs.take(lambda: _wrap(lambda: make_model(r.get("model", "unicycle")), f"robots.{name}.model"))
    pose = errs.take(lambda: as_float_tuple(r.get("pose", [0.0, 0.0, 0.0]), f"robots.{name}.pose", 3))
    path = r.get("path")
    # a path table that did not build has its own error already: the robots naming it say nothing more
    errs.check(path is None or path in paths or path in broken, f"robots.{name}.path", path,
               f"must name a table under [paths]: {', '.join(sorted(paths)) or '(none defined)'}")
    nbrs = r.get("neighbours", [])
    ok_nbrs = errs.check(isinstance(nbrs, list) and all(n in names and n != name for n in nbrs),
                         f"robots.{name}.neighbours", nbrs, "must list other robots of this scenario")
    params = {**defaults, **dict(r.get("controller") or {})}
    kind = params.pop("type", None)
    errs.check(isinstance(kind, str) and _CONTROLLER_RE.fullmatch(kind) is not None, f"robots.{name}.controller.type",
               kind, "expected a registered controller name (see `copath controllers`) or an import path "
               "'package.module:builder'")
    if model is None or pose is None or not ok_nbrs:
        return None
    return RobotSpec(name, model, pose, path, tuple(nbrs), kind, params)


def _wrap(fn: Callable[[], Any], prefix: str) -> Any:
    try:
        return fn()
    except ConfigError:
        raise
    except ValueError as exc:
        raise _sub_error(prefix, exc) from None


def _cross_field(run: RunConfig | None, robots: list[RobotSpec], errs: _Errors) -> None:
    """Rules that involve several tables: settle within the run, start poses apart."""
    if run is not None:
        errs.check(run.settle_s < run.duration_s, "run.settle_s", run.settle_s,
                   f"must be less than run.duration_s = {run.duration_s} (errors are measured after settling)")
    for a, b in itertools.combinations(robots, 2):
        gap = math.hypot(a.pose[0] - b.pose[0], a.pose[1] - b.pose[1])
        need = a.model.radius + b.model.radius
        errs.check(gap >= need, f"robots.{b.name}.pose", list(b.pose),
                   f"starts {gap:.3f} m from robots.{a.name} (pose {list(a.pose)}); start poses must be at least "
                   f"the sum of the two radii apart ({need:.3f} m)")


def parse_scenario(raw: Mapping[str, Any], base_dir: pathlib.Path | None = None, source: str = "",
                   checks: Callable[["Scenario"], list[str]] | None = None) -> Scenario:
    """Validate a scenario table.

    Raises :class:`ConfigErrors` (a ConfigError) listing *every* problem found, each as
    ``key = value is not allowed; rule``. ``checks(scenario)`` adds the problems a caller
    knows how to find (the orchestrator checks each robot's controller with it); it sees
    the scenario as far as it parsed, so its problems are reported with the others.
    """
    raw = copy.deepcopy(dict(raw))
    errs = _Errors()
    # make the table self-contained: data files are read into it once, here
    if raw.get("controller"):
        raw["controller"] = errs.take(lambda: _resolve_files(dict(raw["controller"]), base_dir, "controller"),
                                      dict(raw["controller"]))
    for i, r in enumerate(raw.get("robots") or []):
        if isinstance(r, dict) and r.get("controller"):
            r["controller"] = errs.take(lambda: _resolve_files(dict(r["controller"]), base_dir,
                                                               f"robots[{i}].controller"), dict(r["controller"]))
    for k in raw:
        errs.check(k in _TOP_KEYS, k, raw[k], f"allowed top-level keys: {', '.join(sorted(_TOP_KEYS))}")
    sid = raw.get("id")
    errs.check(isinstance(sid, str) and _ID_RE.fullmatch(sid) is not None, "id", sid,
               "expected a scenario name of letters, digits, '-', '_' and '.', e.g. 'my-test'")
    experiment = raw.get("experiment")
    errs.check(experiment is None or (isinstance(experiment, str) and _EXPERIMENT_RE.fullmatch(experiment) is not None),
               "experiment", experiment,
               "expected a dissertation experiment id in lower case, e.g. 'e5.5' (or leave the key out)")
    run_tab = dict(raw.get("run") or {})
    kills_raw = run_tab.pop("kills", []) or []
    if not errs.check(isinstance(kills_raw, list), "run.kills", kills_raw, "expected a list of tables {robot, at_s}"):
        kills_raw = []
    kills = [k for k in (errs.take(lambda: _kill(k, f"run.kills[{i}]")) for i, k in enumerate(kills_raw))
             if k is not None]
    run = errs.take(lambda: from_table(RunConfig, run_tab, "run"))
    if run is not None:
        run = dataclasses.replace(run, kills=tuple(kills))
    net_tab = dict(raw.get("network") or {})
    parts = [p for p in (errs.take(lambda: _partition(p, f"network.partitions[{i}]"))
                         for i, p in enumerate(net_tab.pop("partitions", []) or [])) if p is not None]
    silences = [p for p in (errs.take(lambda: _silence(p, f"network.silence[{i}]"))
                            for i, p in enumerate(net_tab.pop("silence", []) or [])) if p is not None]
    network = errs.take(lambda: from_table(NetworkConfig, net_tab, "network"), NetworkConfig())
    network = NetworkConfig(**{**network.__dict__, "partitions": tuple(parts), "silence": tuple(silences)})
    noise = errs.take(lambda: from_table(NoiseConfig, raw.get("noise"), "noise"), NoiseConfig())
    sensors = errs.take(lambda: from_table(SensorConfig, raw.get("sensors"), "sensors"), SensorConfig())

    paths: dict[str, Path] = {}
    for name, spec in (raw.get("paths") or {}).items():
        path = errs.take(lambda: _wrap(lambda: make_path(dict(spec) if isinstance(spec, dict) else spec),
                                       f"paths.{name}"))
        if path is not None:
            paths[name] = path

    defaults = dict(raw.get("controller") or {})
    robots_raw = raw.get("robots") or []
    robots: list[RobotSpec] = []
    if errs.check(isinstance(robots_raw, list) and robots_raw, "robots", robots_raw,
                  "need at least one [[robots]] entry"):
        names = [r.get("name") if isinstance(r, dict) else None for r in robots_raw]
        broken = frozenset(set(raw.get("paths") or {}) - set(paths))
        robots = [s for s in (_robot(r, i, names, paths, defaults, errs, broken) for i, r in enumerate(robots_raw))
                  if s is not None]
    # the fixed graph must be undirected: neighbour lists are symmetrised
    order = [r.name for r in robots]
    sym = {r.name: set(r.neighbours) for r in robots}
    for r in robots:
        for n in r.neighbours:
            sym.setdefault(n, set()).add(r.name)
    robots = [RobotSpec(r.name, r.model, r.pose, r.path, tuple(sorted(sym[r.name] & set(order), key=order.index)),
                        r.controller, r.params) for r in robots]
    edges = {frozenset((r.name, n)) for r in robots for n in r.neighbours}
    for i, p in enumerate(parts):
        for a, b in p.links:
            if errs.check(a in order and b in order and a != b, f"network.partitions[{i}].links", [a, b],
                          "must name two robots of this scenario"):
                errs.check(network.range_m > 0 or frozenset((a, b)) in edges, f"network.partitions[{i}].links",
                           [a, b], "must be an edge of the communication graph (robots.neighbours)")

    for i, sil in enumerate(network.silence):
        errs.check(sil.robot in order, f"network.silence[{i}].robot", sil.robot, "must name a robot of this scenario")
    for i, kill in enumerate(kills):
        if errs.check(kill.robot in order, f"run.kills[{i}].robot", kill.robot,
                      f"must name a robot of this scenario ({', '.join(order)})"):
            errs.check(sum(k.robot == kill.robot and abs(k.at_s - kill.at_s) < 1e-9 for k in kills) == 1,
                       f"run.kills[{i}]", {"robot": kill.robot, "at_s": kill.at_s}, "is declared twice")

    obstacles = [o for o in (errs.take(lambda: _obstacle(o, f"obstacles[{i}]"))
                             for i, o in enumerate(raw.get("obstacles") or [])) if o is not None]
    metrics = errs.take(lambda: parse_metrics(raw.get("metrics"), tuple(r.name for r in robots)), {})
    if metrics.get("path_offsets"):
        for r in robots:
            errs.check(r.path is not None, f"robots.{r.name}.path", r.path,
                       "metrics.path_offsets scores each robot along its path: name a table under [paths]")
    targets = errs.take(lambda: parse_targets(raw.get("targets")), ())
    sensing = errs.take(lambda: parse_sensing(raw.get("sensing"), order), SensingConfig())
    if sensing.enabled and any(v > 0 for v in noise.pose_std):
        errs.check(all(sensing.profile_for(r.name, r.model.kind).ideal for r in robots), "noise.pose_std",
                   list(noise.pose_std), "must be 0 when a [sensing] profile is not ideal (the profile models the noise)")
    safety = errs.take(lambda: from_table(SafetyConfig, raw.get("safety"), "safety"), SafetyConfig())
    if run is not None:
        errs.check(not safety.enabled or safety.gamma is None or safety.gamma * run.dt <= 1.0 + 1e-12,
                   "safety.gamma", safety.gamma,
                   f"must be <= 1/run.dt = {1.0 / run.dt:g} 1/s so a barrier cannot be overshot in one period")
    _cross_field(run, robots, errs)
    world = errs.take(lambda: parse_world(raw.get("world"), {r.name: r.pose for r in robots}), WorldConfig())
    if world.ros2:  # ROS 2 robots run on the wall clock and report their own poses (docs/reference/ros2.md)
        errs.check(run is None or run.clock == "realtime", "run.clock", run.clock if run else None,
                   "world.backend = 'ros2' drives real robots on the wall clock: set run.clock = 'realtime'")
        errs.check(not sensors.enabled, "sensors.enabled", sensors.enabled,
                   "world.backend = 'ros2' has no simulated range sensors")
        errs.check(all(sensing.profile_for(r.name, r.model.kind).ideal for r in robots), "sensing",
                   raw.get("sensing"), "world.backend = 'ros2' feeds the robots' reported poses; sensor profiles "
                   "are simulated only")
    scenario = Scenario(
        id=sid,
        experiment=experiment,
        title=str(raw.get("title", sid)),
        run=run if run is not None else RunConfig(),
        network=network,
        noise=noise,
        sensors=sensors,
        paths=paths,
        robots=tuple(robots),
        obstacles=tuple(obstacles),
        metrics=metrics,
        raw=raw,
        source=source,
        targets=targets,
        sensing=sensing,
        safety=safety,
        world=world,
    )
    if checks is not None:
        errs.items.extend(checks(scenario))
    if errs.items:
        raise ConfigErrors(errs.items)
    return scenario


_HEADER_RE = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_\-\"][A-Za-z0-9_\-\". ]*?)\s*\]\]?\s*(?:#.*)?$")
_KEY_RE = re.compile(r"^\s*([A-Za-z0-9_\-\".]+)\s*=")
_INLINE_KEY_RE = re.compile(r"[{,]\s*([A-Za-z0-9_\-]+)\s*=")
_ERROR_KEY_RE = re.compile(r"^([A-Za-z_][\w\-]*(?:\[\d+\])?(?:\.[\w\-]+(?:\[\d+\])?)*)(?: = |: )")


def key_lines(text: str) -> dict[str, int]:
    """Line (1-based) of every key of a TOML scenario, by its dotted location as the error
    messages name it: ``run.dt``, ``controller.k1``, ``robots[0].pose`` and ``robots.r1.pose``
    (by the entry's name), ``paths.main.a``, keys of inline tables too.

    TOML readers give no line numbers for keys, so the text is searched: a line-based
    reading of headers, ``key = value`` lines and one level of inline tables, which covers
    how scenarios are written; a key it cannot place has no line."""
    out: dict[str, int] = {}
    table: list[str] = []
    counts: dict[str, int] = {}
    names: dict[str, str] = {}  # "robots[0]" -> "robots.r1"

    def put(key: str, line: int) -> None:
        out.setdefault(key, line)

    depth = 0  # open brackets of a multi-line array value
    for n, line in enumerate(text.splitlines(), start=1):
        code = line.split("#", 1)[0] if '"' not in line.split("#", 1)[0] else line
        if depth > 0:  # inside a value that spans lines: no keys or headers here
            depth += code.count("[") - code.count("]")
            continue
        m = _HEADER_RE.match(code)
        if m:
            parts = [s.strip().strip('"') for s in m.group(2).split(".")]
            if m.group(1) == "[[":  # an array of tables: the next entry
                arr = ".".join(parts)
                i = counts[arr] = counts.get(arr, -1) + 1
                table = parts[:-1] + [f"{parts[-1]}[{i}]"]
            else:
                # [robots.controller] after [[robots]] belongs to the last robots entry
                head = parts[0]
                table = ([f"{head}[{counts[head]}]"] + parts[1:]) if head in counts else parts
            for j in range(1, len(parts) + 1):  # the implicit super-tables, and the array itself
                put(".".join(parts[:j]), n)
            put(".".join(table), n)
            continue
        m = _KEY_RE.match(code)
        if not m:
            continue
        dotted = [s.strip().strip('"') for s in m.group(1).split(".")]
        for j in range(1, len(dotted)):  # a dotted key defines its parents too
            put(".".join([*table, *dotted[:j]]), n)
        key = ".".join([*table, *dotted])
        put(key, n)
        rest = code[m.end():]
        depth = max(0, rest.count("[") - rest.count("]"))
        if rest.lstrip().startswith("{"):
            for k in _INLINE_KEY_RE.findall(rest):
                put(f"{key}.{k}", n)
        if table and table[-1].startswith("robots[") and m.group(1) == "name":
            v = rest.strip().strip('"').strip("'")
            names[table[-1]] = f"robots.{v}"
    for key, line in list(out.items()):
        for idx, named in names.items():
            if key == idx or key.startswith(idx + "."):
                out.setdefault(named + key[len(idx):], line)
    return out


def locate_errors(errors: list[str], text: str, skip: tuple[str, ...] = ()) -> list[str]:
    """``errors`` with ``line N: `` in front of each whose key (or the nearest table above it)
    is found in ``text``; keys under a prefix in ``skip`` (values set by ``--set``) are left
    without a line, since the file's line is not where their value came from."""
    lines = key_lines(text)
    out = []
    for e in errors:
        m = _ERROR_KEY_RE.match(e)
        key = m.group(1) if m else None
        if key is None or any(key == s or key.startswith(s + ".") or key.startswith(s + "[") for s in skip):
            out.append(e)
            continue
        probe, line = key, None
        while probe:
            line = lines.get(probe)
            if line is not None:
                break
            probe = re.sub(r"(\.[^.\[]+|\[\d+\])$", "", probe) if re.search(r"(\.[^.\[]+|\[\d+\])$", probe) else ""
        out.append(f"line {line}: {e}" if line is not None else e)
    return out


def load_scenario(path: str | pathlib.Path, checks: Callable[["Scenario"], list[str]] | None = None) -> Scenario:
    """Read and validate a scenario file (entry points only); ``checks`` as in :func:`parse_scenario`."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ConfigError(f"scenario file {str(path)!r} does not exist")
    if path.suffix == ".json":  # an effective scenario written by the orchestrator
        try:
            raw = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path.name}: not valid JSON: {exc}") from exc
        return parse_scenario(raw, base_dir=path.parent, source=str(raw.get("_source", path.name)), checks=checks)
    text = path.read_text()
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path.name}: not valid TOML: {exc}") from exc
    try:
        return parse_scenario(raw, base_dir=path.parent, source=path.name, checks=checks)
    except ConfigErrors as exc:
        raise ConfigErrors(locate_errors(exc.errors, text)) from None
