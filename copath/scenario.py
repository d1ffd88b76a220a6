"""Scenario model: one validated object per ``configs/*.toml`` file.

The TOML layout (every table optional unless said)::

    id = "my-test"                   # free scenario name: letters, digits, "-", "_", "."
    experiment = "e5.5"              # optional: the dissertation experiment it reproduces
    title = "..."
    [run]       duration_s, dt, clock ("lockstep" | "realtime"), settle_s, seed,
                tick_timeout_s, rate_hz (realtime controller rate; default 1/dt)
    [network]   delay_ms, jitter_ms, loss, burst_p_gb, burst_p_bg, burst_loss,
                range_m (0 = fixed graph from robots.neighbours),
                partitions = [{links = [["r1", "r2"]], start_s, end_s}]
    [noise]     pose_std = [sx, sy, stheta], range_std
    [sensors]   enabled, count, max_range_m
    [paths.NAME] type = "lemniscate" | "eight" | ... and the curve's keys (copath.paths)
    [controller] type = "<registered controller>" and its parameters (defaults for all)
    [[robots]]  name, model ("omni" | "unicycle" | table), pose = [x, y, theta], path,
                neighbours = [...], [robots.controller] per-robot overrides
    [[obstacles]] vertices = [[x, y], ...], velocity = [vx, vy] (optional)
    [metrics]   coordination_pairs = "all" | "edges"
    [targets]   metric key = threshold, e.g. coordination_error_max_m = 0.1 (copath.targets)

Controller parameters whose key ends in ``_file`` (a string) or ``_files`` (a list) are
data files relative to the scenario file; the loader replaces them by their content
(JSON, or CSV of ``x,y`` rows) under the key without the suffix.

Parsing from a file happens only in the entry points (orchestrator, agent/sim nodes);
:func:`parse_scenario` takes the already-read table.
"""

from __future__ import annotations

import copy
import csv
import json
import math
import pathlib
import re
import tomllib
from dataclasses import dataclass, field
from typing import Any, Mapping

from .config import ConfigError, as_float_tuple, from_table, require
from .models import OmniModel, UnicycleModel, make_model
from .paths import Path, make_path
from .targets import Target, parse_targets

__all__ = [
    "Scenario",
    "RunConfig",
    "NetworkConfig",
    "NoiseConfig",
    "SensorConfig",
    "RobotSpec",
    "ObstacleSpec",
    "parse_scenario",
    "load_scenario",
    "ConfigError",
]

CLOCKS = ("lockstep", "realtime")
_ID_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
_CONTROLLER_RE = re.compile(r"[A-Za-z_][\w.-]*|[A-Za-z_][\w.]*:[A-Za-z_]\w*")
_EXPERIMENT_RE = re.compile(r"e[4-6]\.[0-9]+")


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

    def __post_init__(self) -> None:
        require(self.duration_s > 0, "run.duration_s", self.duration_s, "must be > 0")
        require(self.dt > 0, "run.dt", self.dt, "must be > 0")
        require(self.clock in CLOCKS, "run.clock", self.clock, f"allowed: {', '.join(CLOCKS)}")
        require(self.settle_s >= 0, "run.settle_s", self.settle_s, "must be >= 0")
        require(self.tick_timeout_s > 0, "run.tick_timeout_s", self.tick_timeout_s, "must be > 0")
        require(self.physics_dt > 0, "run.physics_dt", self.physics_dt, "must be > 0")


@dataclass(frozen=True)
class Partition:
    links: tuple[tuple[str, str], ...]
    start_s: float
    end_s: float


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
    targets: tuple[Target, ...] = ()
    """Goals a run is graded against (``[targets]``, :func:`copath.targets.grade`)."""

    @property
    def robot_names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.robots)

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


_TOP_KEYS = {"_source", "id", "experiment", "title", "run", "network", "noise", "sensors", "paths", "controller", "robots",
             "obstacles", "metrics", "targets", "notes"}


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


def parse_scenario(raw: Mapping[str, Any], base_dir: pathlib.Path | None = None, source: str = "") -> Scenario:
    """Validate a scenario table; raises ConfigError naming key, value and rule."""
    raw = copy.deepcopy(dict(raw))
    # make the table self-contained: data files are read into it once, here
    if raw.get("controller"):
        raw["controller"] = _resolve_files(dict(raw["controller"]), base_dir, "controller")
    for i, r in enumerate(raw.get("robots") or []):
        if isinstance(r, dict) and r.get("controller"):
            r["controller"] = _resolve_files(dict(r["controller"]), base_dir, f"robots[{i}].controller")
    for k in raw:
        require(k in _TOP_KEYS, k, raw[k], f"allowed top-level keys: {', '.join(sorted(_TOP_KEYS))}")
    sid = raw.get("id")
    require(isinstance(sid, str) and _ID_RE.fullmatch(sid) is not None, "id", sid,
            "expected a scenario name of letters, digits, '-', '_' and '.', e.g. 'my-test'")
    experiment = raw.get("experiment")
    require(experiment is None or (isinstance(experiment, str) and _EXPERIMENT_RE.fullmatch(experiment) is not None),
            "experiment", experiment,
            "expected a dissertation experiment id in lower case, e.g. 'e5.5' (or leave the key out)")
    run = from_table(RunConfig, raw.get("run"), "run")
    net_tab = dict(raw.get("network") or {})
    parts = []
    for i, p in enumerate(net_tab.pop("partitions", []) or []):
        where = f"network.partitions[{i}]"
        require(isinstance(p, dict), where, p, "expected a table {links, start_s, end_s}")
        links = p.get("links")
        require(isinstance(links, list) and all(isinstance(l, list) and len(l) == 2 for l in links),
                f"{where}.links", links, "expected a list of [robot, robot] pairs")
        start, end = float(p.get("start_s", 0.0)), float(p.get("end_s", math.inf))
        require(end > start, f"{where}.end_s", end, "must be greater than start_s")
        parts.append(Partition(tuple((str(a), str(b)) for a, b in links), start, end))
    network = from_table(NetworkConfig, net_tab, "network")
    network = NetworkConfig(**{**network.__dict__, "partitions": tuple(parts)})
    noise = from_table(NoiseConfig, raw.get("noise"), "noise")
    sensors = from_table(SensorConfig, raw.get("sensors"), "sensors")

    paths: dict[str, Path] = {}
    for name, spec in (raw.get("paths") or {}).items():
        try:
            paths[name] = make_path(dict(spec))
        except ValueError as exc:
            raise ConfigError(f"paths.{name}: {exc}") from exc

    defaults = dict(raw.get("controller") or {})
    robots_raw = raw.get("robots") or []
    require(isinstance(robots_raw, list) and robots_raw, "robots", robots_raw, "need at least one [[robots]] entry")
    names = [r.get("name") for r in robots_raw]
    robots = []
    allowed_robot_keys = {"name", "model", "pose", "path", "neighbours", "controller"}
    for i, r in enumerate(robots_raw):
        where = f"robots[{i}]"
        for k in r:
            require(k in allowed_robot_keys, f"{where}.{k}", r[k], f"allowed keys: {', '.join(sorted(allowed_robot_keys))}")
        name = r.get("name")
        require(isinstance(name, str) and name.isidentifier(), f"{where}.name", name,
                "expected an identifier such as 'r1' (letters, digits, underscore)")
        require(names.count(name) == 1, f"{where}.name", name, "robot names must be unique")
        try:
            model = make_model(r.get("model", "unicycle"))
        except ValueError as exc:
            raise ConfigError(f"robots.{name}.model: {exc}") from exc
        pose = as_float_tuple(r.get("pose", [0.0, 0.0, 0.0]), f"robots.{name}.pose", 3)
        path = r.get("path")
        require(path is None or path in paths, f"robots.{name}.path", path,
                f"must name a table under [paths]: {', '.join(sorted(paths)) or '(none defined)'}")
        nbrs = tuple(r.get("neighbours", []))
        for n in nbrs:
            require(n in names and n != name, f"robots.{name}.neighbours", list(nbrs),
                    "must list other robots of this scenario")
        params = {**defaults, **dict(r.get("controller") or {})}
        kind = params.pop("type", None)
        require(isinstance(kind, str) and _CONTROLLER_RE.fullmatch(kind) is not None, f"robots.{name}.controller.type",
                kind, "expected a registered controller name (see `copath controllers`) or an import path "
                "'package.module:builder'")
        robots.append(RobotSpec(name, model, pose, path, nbrs, kind, params))
    # the fixed graph must be undirected: neighbour lists are symmetrised
    sym = {r.name: set(r.neighbours) for r in robots}
    for r in robots:
        for n in r.neighbours:
            sym[n].add(r.name)
    robots = [RobotSpec(r.name, r.model, r.pose, r.path, tuple(sorted(sym[r.name], key=names.index)),
                        r.controller, r.params) for r in robots]
    for i, p in enumerate(parts):
        for a, b in p.links:
            require(a in names and b in names, f"network.partitions[{i}].links", [a, b], "must name robots of this scenario")

    obstacles = []
    for i, o in enumerate(raw.get("obstacles") or []):
        where = f"obstacles[{i}]"
        verts = o.get("vertices")
        require(isinstance(verts, list) and len(verts) >= 3, f"{where}.vertices", verts, "expected >= 3 [x, y] points")
        vs = tuple(as_float_tuple(v, f"{where}.vertices[{j}]", 2) for j, v in enumerate(verts))
        vel = as_float_tuple(o.get("velocity", [0.0, 0.0]), f"{where}.velocity", 2)
        for k in o:
            require(k in ("vertices", "velocity"), f"{where}.{k}", o[k], "allowed keys: vertices, velocity")
        obstacles.append(ObstacleSpec(vs, vel))

    metrics = dict(raw.get("metrics") or {})
    targets = parse_targets(raw.get("targets"))
    return Scenario(
        id=sid,
        experiment=experiment,
        title=str(raw.get("title", sid)),
        run=run,
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
    )


def load_scenario(path: str | pathlib.Path) -> Scenario:
    """Read and validate a scenario file (entry points only)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ConfigError(f"scenario file {str(path)!r} does not exist")
    if path.suffix == ".json":  # an effective scenario written by the orchestrator
        try:
            raw = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{path.name}: not valid JSON: {exc}") from exc
        return parse_scenario(raw, base_dir=path.parent, source=str(raw.get("_source", path.name)))
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path.name}: not valid TOML: {exc}") from exc
    return parse_scenario(raw, base_dir=path.parent, source=path.name)
