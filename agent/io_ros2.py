"""``copath agent ... --io ros2``: one robot's agent on the robot's own computer (docs/reference/ros2.md).

The agent reads its robot's pose from ROS 2 and publishes its commands on the robot's
``cmd_vel`` itself, with no bridge hop; it talks to its neighbours, the recorder and the
run's ROS 2 bridge over Zenoh as any agent does. The robot's entry in the scenario says
so: ``[world.robots.NAME] commands = "agent"`` (the bridge then neither forwards that
robot's poses nor publishes its commands; it records the reported poses, gates the start
and, when the agent is gone or the run ends, sends zeros).

- each pose message becomes the agent's observation at once (the same ``Obs`` the bridge
  would have sent), mapped by the robot's ``origin``;
- each command the controller publishes goes out as a geometry_msgs/Twist, saturated by
  the model's limits, and is re-sent at ``world.cmd_rate_hz`` (drivers' watchdogs);
- SIGINT, SIGTERM, the end of the run or an error: a zero Twist at once, and zeros for
  0.5 s (the bridge's rule, ``sim.ros2_bridge.ZERO_HOLD_S``).
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Callable

import numpy as np

from copath.ros2 import frames
from copath.scenario import Scenario
from copath.wire.link import Callback, Link, RejectCallback
from copath.wire.messages import Command, End, Obs
from copath.wire.trust import RejectLog

logger = logging.getLogger("copath.agent.ros2")

__all__ = ["problem", "Ros2RobotIO", "CommandTap"]

ZERO_HOLD_S = 0.5
ZERO_PERIOD_S = 0.02


def problem(scenario: Scenario, robot: str) -> str | None:
    """Why ``--io ros2`` cannot run ``robot`` of ``scenario`` (one line), or None."""
    from copath.ros2 import missing  # noqa: PLC0415

    if (m := missing("--io ros2")) is not None:
        return m
    if not scenario.world.ros2:
        return (f"--io ros2 is not allowed with world.backend = {scenario.world.backend!r}; the robot's pose "
                "comes from ROS 2 only in a ROS 2 world (world.backend = 'ros2')")
    if scenario.world.robots[robot].commands != "agent":
        return (f"--io ros2 is not allowed for robot {robot}: world.robots.{robot}.commands = 'bridge' (the bridge "
                f"drives it); set world.robots.{robot}.commands = 'agent' in the scenario")
    return None


class Ros2RobotIO:
    """The robot's pose in, its Twist out (rclpy on a thread of its own)."""

    def __init__(self, scenario: Scenario, robot: str, on_obs, counts: dict | None = None) -> None:
        from geometry_msgs.msg import PoseStamped, Twist  # noqa: PLC0415
        from nav_msgs.msg import Odometry  # noqa: PLC0415

        from copath.ros2 import io  # noqa: PLC0415

        self._io = io
        self.robot = robot
        self.rio = scenario.world.robots[robot]
        self.model = scenario.robot(robot).model
        self.omni = self.model.kind == "omni"
        self.on_obs = on_obs
        self.wall_t0: float | None = None
        self.dt = scenario.run.dt
        self.ended = False
        self.cmd = np.zeros(self.model.command_size)
        self.closing = False
        self.counts = {} if counts is None else counts  # the agent's closing account
        for k in ("ros2_poses", "ros2_frame_rejects", "ros2_twists", "ros2_saturated"):
            self.counts.setdefault(k, 0)
        self.lock = threading.RLock()
        self.spin = io.Spinner(f"copath_agent_{robot}")
        node = self.spin.node
        typ = Odometry if self.rio.pose_type == "odometry" else PoseStamped
        node.create_subscription(typ, self.rio.pose_topic, self._on_pose, io.qos_pose())
        self.pub = node.create_publisher(Twist, self.rio.cmd_topic, io.qos_cmd())
        self._period = 1.0 / scenario.world.cmd_rate_hz
        self._sent_at = 0.0
        self._stop = threading.Event()
        self._resender = threading.Thread(target=self._resend, name="cmd-resend", daemon=True)
        self.spin.start()
        self._resender.start()

    def _on_pose(self, msg) -> None:
        if self.rio.frame and msg.header.frame_id != self.rio.frame:
            self.counts["ros2_frame_rejects"] += 1
            return
        if self.ended:  # after the run's end record (more observations would make it look forged)
            return
        p = frames.to_scenario(self.rio.origin, self._io.pose_of(msg))
        self.counts["ros2_poses"] += 1
        t = 0.0 if self.wall_t0 is None else time.time() - self.wall_t0
        k = int(t / self.dt)  # the tick of the bridge's world record at t: telemetry lines up with it
        self.on_obs(Obs(k, float(t), [float(v) for v in p]))

    def command(self, cmd) -> None:
        """The controller's command: saturated, then published (until :meth:`stop`)."""
        sat, viol = self.model.saturate(cmd)
        with self.lock:
            if self.closing:
                return
            self.cmd = np.asarray(sat, dtype=float)
            self.counts["ros2_saturated"] += int(viol)
            self._publish(self.cmd)

    def _publish(self, cmd) -> None:
        self.pub.publish(self._io.twist(cmd, self.omni))
        self._sent_at = time.monotonic()
        self.counts["ros2_twists"] += 1

    def _resend(self) -> None:
        while not self._stop.wait(self._period / 2):
            with self.lock:
                if not self.closing and time.monotonic() - self._sent_at >= self._period:
                    self._publish(self.cmd)

    def stop_now(self) -> None:
        with self.lock:
            self.closing = True
            self.cmd = np.zeros_like(self.cmd)
            self._publish(self.cmd)

    def close(self) -> None:
        """Zero Twists for ``ZERO_HOLD_S``, then shut ROS 2 down."""
        self.stop_now()
        end = time.monotonic() + ZERO_HOLD_S
        while time.monotonic() < end:
            time.sleep(ZERO_PERIOD_S)
            with self.lock:
                self._publish(self.cmd)
        self._stop.set()
        self._resender.join(timeout=1.0)
        self.spin.close()


class CommandTap:
    """A :class:`copath.wire.link.Link` that sends the robot's own commands to its ROS 2
    driver as well; everything else is the wrapped link's."""

    def __init__(self, link: Link, cmd_key: str, ros: Ros2RobotIO) -> None:
        self._link = link
        self._cmd_key = cmd_key
        self._ros = ros

    @property
    def published(self) -> int:
        return self._link.published

    @property
    def rejects(self) -> int:
        return self._link.rejects

    @property
    def synchronous(self) -> bool:
        return self._link.synchronous

    @property
    def reject_log(self) -> RejectLog:
        return self._link.reject_log

    def publish(self, key: str, record) -> None:
        if key == self._cmd_key and isinstance(record, Command):
            self._ros.command(record.cmd)
        self._link.publish(key, record)

    def subscribe(self, key_expr: str, callback: Callback, on_reject: RejectCallback | None = None) -> None:
        self._link.subscribe(key_expr, callback, on_reject)

    def declare_token(self, key: str) -> None:
        self._link.declare_token(key)

    def watch_liveliness(self, key_expr: str, callback: Callable[[str, bool], None]) -> None:
        self._link.watch_liveliness(key_expr, callback)

    def drop_when_congested(self, *key_exprs: str) -> None:
        self._link.drop_when_congested(*key_exprs)

    def close(self) -> None:
        self._link.close()


def run(runtime, keys, link, clock: str) -> None:
    """Serve the run with the robot's ROS 2 I/O in place of the simulator's observations."""
    from .node import AgentNode  # noqa: PLC0415

    holder: dict = {}
    ros = Ros2RobotIO(runtime.scenario, runtime.name, lambda obs: holder["node"]._on_obs(keys.obs(runtime.name), obs)
                      if "node" in holder else None, runtime.counters.extra)

    class _Stop(Exception):
        pass

    def _on_signal(signum, frame) -> None:
        ros.stop_now()
        raise _Stop()

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    def _on_end(key: str, rec) -> None:
        if isinstance(rec, End):
            ros.ended = True

    try:
        link.subscribe(keys.end, _on_end)
        node = AgentNode(runtime, keys, CommandTap(link, keys.cmd(runtime.name), ros), clock)
        holder["node"] = node
        waiter = threading.Thread(target=lambda: (node.started.wait(), setattr(ros, "wall_t0", node.wall_t0)),
                                  daemon=True)
        waiter.start()
        node.run()
    except _Stop:
        logger.info("stopped by a signal; the robot was sent zero velocity")
    finally:
        for s in old:
            signal.signal(s, signal.SIG_IGN)
        ros.close()
        for s, h in old.items():
            signal.signal(s, h)
