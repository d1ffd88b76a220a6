"""The ``[world]`` table of a scenario: which world the robots live in (pure).

::

    [world]
    backend = "ros2"              # "sim" (default): copath's simulator; "ros2": ROS 2 robots
    start_timeout_s = 30.0        # wait this long for every robot's first pose
    pose_type = "odometry"        # default pose source of every robot
    cmd_rate_hz = 20.0            # cmd_vel is re-sent at this rate between commands
    [world.robots.r1]             # per robot, every key optional
    pose_topic = "/r1/odom"       # default /<robot>/odom (odometry) or /<robot>/pose (pose_stamped)
    pose_type = "pose_stamped"    # "odometry" (nav_msgs/Odometry) | "pose_stamped" (geometry_msgs/PoseStamped)
    cmd_topic = "/r1/cmd_vel"     # geometry_msgs/Twist; default /<robot>/cmd_vel
    frame = "map"                 # the header.frame_id poses must carry ("": any)
    origin = "start"              # pose of that frame in the scenario's frame: [x, y, theta] or
                                  # "start" (the robot's scenario pose; default for odometry)
    commands = "bridge"           # who publishes cmd_vel: "bridge" or "agent" (copath agent --io ros2)

docs/reference/ros2.md explains each key, the QoS and what the run's log records.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

from ..config import ConfigError, as_float_tuple, require

__all__ = ["BACKENDS", "COMMANDERS", "POSE_TYPES", "RobotIO", "WorldConfig", "parse_world"]

BACKENDS = ("sim", "ros2")
POSE_TYPES = ("odometry", "pose_stamped")
_TOPIC_RE = re.compile(r"/?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*")
_FRAME_RE = re.compile(r"[A-Za-z0-9_/.-]*")
_ROBOT_KEYS = ("pose_topic", "pose_type", "cmd_topic", "frame", "origin", "commands")
COMMANDERS = ("bridge", "agent")
_WORLD_KEYS = ("backend", "start_timeout_s", "pose_type", "cmd_rate_hz", "robots")


@dataclass(frozen=True)
class RobotIO:
    """Where one robot's pose comes from and where its commands go (ROS 2 world)."""

    pose_topic: str
    """Topic of the robot's pose: nav_msgs/Odometry or geometry_msgs/PoseStamped."""
    pose_type: str
    """``odometry`` or ``pose_stamped`` (motion capture)."""
    cmd_topic: str
    """geometry_msgs/Twist commands: linear.x, angular.z (and linear.y for an omni robot)."""
    frame: str = ""
    """The ``header.frame_id`` every pose must carry; others are rejected and counted ("": any)."""
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Pose of the pose source's frame in the scenario's frame [m, m, rad]: a reported pose
    p becomes origin (+) p. ``"start"`` in the scenario (the default for odometry) is the
    robot's start pose: wheel odometry starts at zero where the robot was placed, and the
    robot is placed where the scenario starts it. Motion capture (``pose_stamped``) reports
    in a fixed frame: its default origin is zero."""
    commands: str = "bridge"
    """Who reads the pose and publishes cmd_vel: ``bridge`` (the bridge, for the agent) or
    ``agent``: the robot's agent itself, ``copath agent --io ros2`` on the robot's computer,
    with no bridge hop; the bridge then only records the reported poses and, when the
    agent is gone or the run ends, sends zeros."""


@dataclass(frozen=True)
class WorldConfig:
    backend: str = "sim"
    """``sim``: copath's simulator owns the truth. ``ros2``: a bridge process drives ROS 2
    robots, and the log's world records are the poses they reported (docs/reference/ros2.md)."""
    start_timeout_s: float = 30.0
    """ROS 2: how long the bridge waits for every robot's first pose before tick 0 [s]."""
    cmd_rate_hz: float = 20.0
    """ROS 2: the current command is re-sent at this rate, so that a driver's command
    watchdog (typically 0.2-0.5 s) does not stop a robot between two commands [Hz]."""
    robots: Mapping[str, RobotIO] = field(default_factory=dict)
    """Per robot name: its topics (every robot of the scenario has an entry under ros2)."""

    def __post_init__(self) -> None:
        require(self.backend in BACKENDS, "world.backend", self.backend, f"allowed: {', '.join(BACKENDS)}")
        require(self.start_timeout_s > 0, "world.start_timeout_s", self.start_timeout_s, "must be > 0")
        require(self.cmd_rate_hz > 0, "world.cmd_rate_hz", self.cmd_rate_hz, "must be > 0")

    @property
    def ros2(self) -> bool:
        return self.backend == "ros2"


def _topic(value: Any, key: str) -> str:
    require(isinstance(value, str) and _TOPIC_RE.fullmatch(value) is not None, key, value,
            "expected a ROS 2 topic name such as '/r1/odom' (letters, digits, '_', separated by '/')")
    return value if value.startswith("/") else "/" + value


def _robot_io(name: str, tab: Any, default_type: str, start) -> RobotIO:
    where = f"world.robots.{name}"
    require(isinstance(tab, dict), where, tab, f"expected a table with keys {', '.join(_ROBOT_KEYS)}")
    for k in tab:
        require(k in _ROBOT_KEYS, f"{where}.{k}", tab[k], f"allowed keys: {', '.join(_ROBOT_KEYS)}")
    kind = tab.get("pose_type", default_type)
    require(kind in POSE_TYPES, f"{where}.pose_type", kind, f"allowed: {', '.join(POSE_TYPES)}")
    pose_default = f"/{name}/odom" if kind == "odometry" else f"/{name}/pose"
    frame = tab.get("frame", "")
    require(isinstance(frame, str) and _FRAME_RE.fullmatch(frame) is not None, f"{where}.frame", frame,
            "expected a frame id such as 'map' or 'r1/odom' ('' accepts any)")
    origin = tab.get("origin", "start" if kind == "odometry" else [0.0, 0.0, 0.0])
    if origin == "start":
        origin = tuple(float(v) for v in start)
    elif isinstance(origin, str):
        raise ConfigError(f"{where}.origin = {origin!r} is not allowed; expected [x, y, theta] or 'start'")
    origin = as_float_tuple(origin, f"{where}.origin", 3)
    require(all(math.isfinite(v) for v in origin), f"{where}.origin", list(origin), "must be finite numbers")
    commands = tab.get("commands", "bridge")
    require(commands in COMMANDERS, f"{where}.commands", commands, f"allowed: {', '.join(COMMANDERS)}")
    return RobotIO(_topic(tab.get("pose_topic", pose_default), f"{where}.pose_topic"), kind,
                   _topic(tab.get("cmd_topic", f"/{name}/cmd_vel"), f"{where}.cmd_topic"), frame, origin, commands)


def parse_world(raw: Any, starts: Mapping[str, tuple[float, float, float]]) -> WorldConfig:
    """Validate ``[world]`` for a scenario whose robots start at ``starts`` (name -> pose)."""
    robot_names = tuple(starts)
    if raw is None:
        return WorldConfig()
    require(isinstance(raw, dict), "world", raw, f"expected a table with keys {', '.join(_WORLD_KEYS)}")
    for k in raw:
        require(k in _WORLD_KEYS, f"world.{k}", raw[k], f"allowed keys: {', '.join(_WORLD_KEYS)}")
    default_type = raw.get("pose_type", "odometry")
    require(default_type in POSE_TYPES, "world.pose_type", default_type, f"allowed: {', '.join(POSE_TYPES)}")
    per = raw.get("robots") or {}
    require(isinstance(per, dict), "world.robots", per, "expected a table of robot names, e.g. [world.robots.r1]")
    for name in per:
        if name not in robot_names:
            raise ConfigError(f"world.robots.{name} = {per[name]!r} is not allowed; robots of this scenario: "
                              f"{', '.join(robot_names)}")
    robots = {n: _robot_io(n, per.get(n, {}), default_type, starts[n]) for n in robot_names}
    topics = [t for io in robots.values() for t in (io.pose_topic, io.cmd_topic)]
    dup = sorted({t for t in topics if topics.count(t) > 1})
    require(not dup, "world.robots", dup, "each robot needs its own pose and command topics")
    kw = {k: raw[k] for k in ("backend", "start_timeout_s", "cmd_rate_hz") if k in raw}
    for k in ("start_timeout_s", "cmd_rate_hz"):
        if k in kw:
            require(isinstance(kw[k], (int, float)) and not isinstance(kw[k], bool), f"world.{k}", kw[k],
                    "expected a number")
            kw[k] = float(kw[k])
    return WorldConfig(robots=robots, **kw)
