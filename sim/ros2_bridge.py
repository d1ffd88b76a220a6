"""The ROS 2 world: the simulator's side of the wire, with ROS 2 robots instead of a simulation.

``[world] backend = "ros2"`` (docs/reference/ros2.md): the orchestrator starts this process
(``python -m sim.ros2_bridge``) where it would start the simulator. It is a
:class:`sim.node.SimNode` (same start handshake, liveliness, failure policies, fault
windows, events, end and closing account) whose world is the robots' own reports:

- per robot it subscribes to the pose source of ``[world.robots.NAME]`` (nav_msgs/Odometry
  or geometry_msgs/PoseStamped), maps it into the scenario's frame (``origin``) and sends it
  to the robot's agent as its observation, as soon as it arrives;
- each agent command is saturated by the robot's model limits ((3.2) omni wheel speeds,
  Sec. 5.5.3 unicycle scaling; the saturations are counted) and its acceleration limits,
  then published as geometry_msgs/Twist on the robot's command topic, and re-sent at
  ``world.cmd_rate_hz`` so that drivers' command watchdogs do not stop a robot between
  commands;
- every ``run.dt`` the world record (``sim/truth``) carries the poses the robots
  REPORTED, not a ground truth; the run's first event (``world``) and the log's metadata
  say so;
- before tick 0 it waits ``world.start_timeout_s`` for every robot's first pose and names
  the silent topics; a robot whose pose stops for longer than ``run.lease_s`` is lost and
  ``run.on_robot_failure`` applies;
- on every way the run ends (its end, SIGINT, SIGTERM, a failure, a lost robot, an agent
  whose process went away) every robot gets a zero Twist at once, and zeros keep going
  out for ``ZERO_HOLD_S``.

rclpy is imported only when the bridge runs (:mod:`copath.ros2.io`).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import dataclasses
import logging
import os
import signal
import sys
import threading
import time

import numpy as np

from copath.models import limit_change
from copath.ros2 import frames
from copath.scenario import ConfigError, Scenario, load_scenario
from copath.wire.cli import add_config_arguments, session_config_from_args
from copath.wire.keys import Keys
from copath.wire.link import Link
from copath.wire.messages import Command, End, Obs, Stats

from .node import SimNode, sim_tasks

logger = logging.getLogger("copath.ros2_bridge")

__all__ = ["BridgeNode", "ZERO_HOLD_S", "main"]

ZERO_HOLD_S = 0.5
"""After the end, zero Twists keep going out for this long [s] (docs/reference/ros2.md)."""
ZERO_PERIOD_S = 0.02
"""...every this often [s]."""


class _Stop(Exception):
    """SIGINT or SIGTERM arrived (the robots are already stopped)."""


class BridgeNode(SimNode):
    """A simulator node whose world is ROS 2 robots.

    ``publish(name, cmd)`` sends a body command to a robot (a Twist on its command topic);
    the ROS 2 side calls :meth:`on_pose` with each pose message's content.
    """

    def __init__(self, scenario: Scenario, keys: Keys, link: Link, publish, start_timeout_s: float = 120.0,
                 tasks=None) -> None:
        super().__init__(scenario, keys, link, start_timeout_s, tasks=tasks)
        self.publish_cmd = publish
        self.io = scenario.world.robots
        self.models = {r.name: r.model for r in scenario.robots}
        self.omni = {r.name: r.model.kind == "omni" for r in scenario.robots}
        self._lock = threading.RLock()  # a signal handler on the main thread may re-enter
        self._first = threading.Condition(self._lock)
        self._wake = threading.Event()
        n = {r.name: r.model.command_size for r in scenario.robots}
        self.pose: dict[str, tuple[float, float, float]] = {}
        self.pose_at: dict[str, float] = {}
        self.requested = {k: np.zeros(m) for k, m in n.items()}
        """The latest command of each agent after the model's velocity limits."""
        self.out = {k: np.zeros(m) for k, m in n.items()}
        """What was last published (acceleration-limited towards ``requested``)."""
        self.out_at = {k: 0.0 for k in n}
        self.cmd_at: dict[str, float] = {}
        """When each agent's latest command arrived (monotonic)."""
        self.stale_s = max(0.5, 5.0 * scenario.run.dt)
        """An agent silent this long has its robot's command set to zero (a cut-off or starved
        agent must not leave its robot driving on its last command) [s]."""
        self.violated = {k: False for k in n}
        self.held: set[str] = set()
        """Robots held at zero: lost pose, agent gone, or the run is over."""
        self.pose_lost: set[str] = set()
        self.closing = False
        self._t0: float | None = None
        self.wall_t0 = 0.0
        self.k = 0
        self._forwarded = {k: collections.deque(maxlen=256) for k in n}
        """Per robot: (wall time forwarded, pose stamp) of its recent observations."""
        self.latency_s: list[float] = []
        """Pose stamp -> cmd_vel publish of every agent command [s] (same clock: same machine)."""
        self.counts = {"poses": {k: 0 for k in n}, "frame_rejects": {k: 0 for k in n},
                       "saturated": {k: 0 for k in n}, "commands": {k: 0 for k in n},
                       "held_commands": {k: 0 for k in n}, "stale_stops": {k: 0 for k in n}, "twists": 0}
        self.stopped_at: float | None = None
        """Monotonic time at which the first zero Twists went out."""

    # -- ROS 2 side (rclpy's thread) ------------------------------------------------------
    def on_pose(self, name: str, pose, stamp: float, frame: str) -> None:
        """A pose of ``name`` (in its source's frame, stamped on the sender's clock)."""
        io = self.io.get(name)
        if io is None:
            return
        if io.frame and frame != io.frame:
            self.counts["frame_rejects"][name] += 1
            if self.counts["frame_rejects"][name] == 1:
                logger.warning("robot %s: pose in frame %r on %s, expected %r; ignored", name, frame,
                               io.pose_topic, io.frame)
            return
        p = frames.to_scenario(io.origin, pose)
        now = time.monotonic()
        with self._lock:
            first = name not in self.pose
            self.pose[name] = p
            self.pose_at[name] = now
            self.counts["poses"][name] += 1
            if first:
                self._first.notify_all()
            if self._t0 is None or self.closing:
                return
            if io.commands == "agent":  # its agent reads the pose itself (copath agent --io ros2)
                return
            self._forwarded[name].append((time.time(), stamp))
            # under the lock: no observation can follow the end record (agents take that for a forgery)
            self.link.publish(self.keys.obs(name), Obs(self.k, float(now - self._t0), [float(v) for v in p]))

    # -- commands (Zenoh's thread) -----------------------------------------------------------
    def _on_cmd(self, key: str, rec) -> None:
        if not isinstance(rec, Command):
            return
        name = self.keys.relative(key).split("/")[1]
        model = self.models.get(name)
        if model is None:
            return
        with self._lock:
            if self.closing or name in self.held:
                self.counts["held_commands"][name] += 1
                return
            try:
                sat, viol = model.saturate(rec.cmd)
            except ValueError:
                self.stale += 1
                return
            self.requested[name] = np.asarray(sat, dtype=float)
            self.cmd_at[name] = time.monotonic()
            self.violated[name] = bool(viol)
            self.counts["saturated"][name] += int(viol)
            self.counts["commands"][name] += 1
            self._send(name, time.monotonic())
            sent = time.time()
            fw = self._forwarded[name]
            decided = self.wall_t0 + rec.t  # the agent's control instant, on this machine's clock
            i = bisect.bisect_right([w for w, _ in fw], decided) - 1
            if i >= 0:
                self.latency_s.append(sent - fw[i][1])

    def _send(self, name: str, now: float) -> None:
        """Publish the robot's command: acceleration-limited towards the request (lock held)."""
        dt = min(1.0, max(1e-3, now - self.out_at[name]))
        if self.io[name].commands == "agent":  # its agent publishes the robot's commands itself
            self.out[name] = np.zeros_like(self.requested[name]) if name in self.held else self.requested[name].copy()
            return
        target = np.zeros_like(self.requested[name]) if name in self.held else self.requested[name]
        out = np.asarray(limit_change(self.models[name], self.out[name], target, dt), dtype=float)
        self.out[name], self.out_at[name] = out, now
        self.publish_cmd(name, out)
        self.counts["twists"] += 1

    def _hold(self, name: str, why: str) -> None:
        """Stop a robot now (a zero Twist) and keep it stopped until :meth:`_release`."""
        with self._lock:
            if name in self.held:
                return
            self.held.add(name)
            self.out[name] = np.zeros_like(self.out[name])
            self.out_at[name] = time.monotonic()
            self.publish_cmd(name, self.out[name])
            self.counts["twists"] += 1
        logger.warning("robot %s held at zero velocity: %s", name, why)

    def _release(self, name: str) -> None:
        with self._lock:
            self.held.discard(name)
            self.requested[name] = np.zeros_like(self.requested[name])

    def stop_robots(self) -> None:
        """Every robot gets a zero Twist now; no command after this one moves a robot."""
        with self._lock:
            if not self.closing:
                self.closing = True
                self.stopped_at = time.monotonic()
            for name in self.names:
                self.out[name] = np.zeros_like(self.out[name])
                self.publish_cmd(name, self.out[name])
                self.counts["twists"] += 1

    def hold_zeros(self, seconds: float = ZERO_HOLD_S) -> None:
        """Keep sending zero Twists for ``seconds`` after :meth:`stop_robots` (a driver that
        missed the first, or a command queued in a driver, is overwritten)."""
        self.stop_robots()
        end = (self.stopped_at or time.monotonic()) + seconds
        while time.monotonic() < end:
            time.sleep(min(ZERO_PERIOD_S, max(0.0, end - time.monotonic())))
            self.stop_robots()

    # -- liveliness: an agent whose process went away stops its robot at once -------------------
    def _on_alive(self, key: str, alive: bool) -> None:
        name = key.rsplit("/", 1)[-1]
        if name in self.models and self._started_run and not self.closing:
            if not alive and name in self.alive:
                self._hold(name, "its agent's liveliness token disappeared")
            elif alive and name in self.held and name not in self.pose_lost:
                self._release(name)
        super()._on_alive(key, alive)

    def _apply_transitions(self) -> None:
        super()._apply_transitions()
        for name in self.down:
            if name not in self.held:
                self._hold(name, f"robot lost (policy {self.policy})")

    # -- run ---------------------------------------------------------------------------------
    def _wait_first_poses(self) -> str | None:
        """Wait for every robot's first pose; the reason naming the silent topics, or None."""
        timeout = self.scenario.world.start_timeout_s
        deadline = time.monotonic() + timeout
        with self._first:
            while not set(self.names) <= set(self.pose):
                left = deadline - time.monotonic()
                if left <= 0:
                    silent = [f"{n} ({self.io[n].pose_topic})" for n in self.names if n not in self.pose]
                    return (f"no pose within {timeout:g} s from {', '.join(silent)}: is each robot's driver "
                            f"running on ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}?")
                self._first.wait(timeout=min(left, 0.5))
        return None

    def run(self) -> bool:
        self.start()
        self._event("world", backend="ros2", poses="reported by the robots (not ground truth)",
                    topics={n: {"pose": io.pose_topic, "pose_type": io.pose_type, "cmd": io.cmd_topic}
                            for n, io in self.io.items()},
                    domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0))
        reason = self._wait_first_poses()
        if reason:
            logger.error("%s", reason)
            self._finish(0, reason, False)
            return False
        logger.info("every robot reported its pose; waiting for the agents")
        return super().run()

    def _pose_watch(self, now: float) -> str | None:
        """A robot whose pose stopped for longer than ``run.lease_s`` is lost."""
        lease = self.scenario.run.lease_s
        for name in self.names:
            gap = now - self.pose_at.get(name, now)
            if name not in self.pose_lost and gap > lease:
                self.pose_lost.add(name)
                topic = self.io[name].pose_topic
                self._hold(name, f"no pose on {topic} for {gap:.2f} s")
                if self.policy == "fail":
                    return f"robot {name} lost: no pose on {topic} for {gap:.2f} s (run.lease_s = {lease:g})"
                self._event("robot_lost", robot=name, policy=self.policy, cause="pose", topic=topic)
            elif name in self.pose_lost and gap <= lease:
                self.pose_lost.discard(name)
                if name not in self.down:
                    self._release(name)
                self._event("robot_rejoined", robot=name, cause="pose")
        return None

    def _truth(self, k: int):
        with self._lock:
            for name in self.names:
                self.world.poses[name][:] = self.pose[name]
                self.world.applied[name][:] = self.out[name]
            viol = [bool(self.violated[n]) for n in self.names]
        return dataclasses.replace(self.world.truth(k), violated=viol)

    def _realtime(self) -> tuple[int, bool, str]:
        run = self.scenario.run
        with self._lock:
            self.wall_t0 = time.time()
            self._t0 = time.monotonic()
            now = time.monotonic()
            for name in self.names:
                self.out_at[name] = now
                self.pose_at[name] = max(self.pose_at.get(name, now), now - run.lease_s / 2)
        for name in self.names:  # the observation the agents start from
            self.link.publish(self.keys.obs(name), Obs(0, 0.0, [float(v) for v in self.pose[name]]))
        period = 1.0 / self.scenario.world.cmd_rate_hz
        next_tick, next_send = 0.0, period
        while True:
            now = time.monotonic()
            t = now - self._t0
            if t >= self.duration_s - 1e-9:
                return self.k, True, "duration reached"
            reason = self._lost_reason() or self._pose_watch(now)
            if reason:
                return self.k, False, reason
            self._apply_transitions()
            if t >= next_tick - 1e-9:
                reason = self._fault_windows(next_tick, next_tick + run.dt)
                if reason:
                    return self.k, False, reason
                self.world.t = t
                self.link.publish(self.keys.truth, self._truth(self.k))
                self._reject_event()
                with self._lock:
                    self.k += 1
                next_tick += run.dt
                if self._until_reached():
                    return self.k, True, "tasks done"
            if t >= next_send - 1e-9:
                with self._lock:
                    for name in self.names:
                        if name in self.cmd_at and now - self.cmd_at[name] > self.stale_s:
                            del self.cmd_at[name]  # its agent went quiet: stop the robot, say so once
                            self.requested[name] = np.zeros_like(self.requested[name])
                            self.counts["stale_stops"][name] += 1
                            logger.warning("robot %s: no command for %.2f s; commanding zero", name, self.stale_s)
                        if now - self.out_at[name] >= period * 0.5:
                            self._send(name, now)
                next_send += period
                if next_send < t:
                    next_send = t + period
                    self.overruns += 1
            self._wake.wait(max(0.0, min(next_tick, next_send) - (time.monotonic() - self._t0)))

    def _finish(self, k: int, reason: str, ok: bool) -> None:
        """Stop every robot first; then the end record and the closing account."""
        self.stop_robots()
        self._closing = True
        self._reject_event(closing=True)
        self.link.publish(self.keys.end, End(k, float(self.world.t), reason, ok))
        lat = sorted(self.latency_s)
        counters = {"missed_ticks": self.missed, "stale_commands": self.stale, "physics_overruns": self.overruns,
                    "rejects": self.link.rejects, "world": "ros2", **self.counts,
                    "pose_lost": sorted(self.pose_lost)}
        for q in (50, 99):
            counters[f"cmd_latency_ms_p{q}"] = (round(1e3 * lat[min(len(lat) - 1, int(q / 100 * len(lat)))], 3)
                                                if lat else None)
        counters["cmd_latency_samples"] = len(lat)
        cpu = os.times()
        counters["cpu_s"] = round(cpu.user + cpu.system, 3)
        self.link.publish(self.keys.stats("sim"), Stats("sim", self.link.published, counters))
        self._finished = True


class Ros2Robots:
    """The ROS 2 side of the bridge: a pose subscriber and a Twist publisher per robot."""

    def __init__(self, scenario: Scenario, on_pose) -> None:
        from geometry_msgs.msg import PoseStamped, Twist  # noqa: PLC0415
        from nav_msgs.msg import Odometry  # noqa: PLC0415

        from copath.ros2 import io  # noqa: PLC0415

        self._io = io
        self.spin = io.Spinner("copath_bridge")
        node = self.spin.node
        self.omni = {r.name: r.model.kind == "omni" for r in scenario.robots}
        self.pubs = {}
        for r in scenario.robots:
            rio = scenario.world.robots[r.name]
            typ = Odometry if rio.pose_type == "odometry" else PoseStamped

            def cb(msg, name=r.name):
                try:
                    on_pose(name, io.pose_of(msg), io.stamp_of(msg), msg.header.frame_id)
                except Exception:  # noqa: BLE001  (one bad message must not stop the executor)
                    logger.exception("robot %s: pose message not usable", name)

            node.create_subscription(typ, rio.pose_topic, cb, io.qos_pose())
            self.pubs[r.name] = node.create_publisher(Twist, rio.cmd_topic, io.qos_cmd())
        self.spin.start()

    def publish(self, name: str, cmd) -> None:
        self.pubs[name].publish(self._io.twist(cmd, self.omni[name]))

    def close(self) -> None:
        self.spin.close()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="copath ros2-bridge",
                                description="Run the ROS 2 world of a copath run (in place of the simulator).")
    p.add_argument("--run-id", required=True)
    p.add_argument("--config", required=True, help="scenario file (.toml, or the run's scenario.json)")
    p.add_argument("--tasks", default=None,
                   help="the robots' task queues for run.until = 'tasks_done', JSON (copath run passes it)")
    p.add_argument("--start-timeout", type=float, default=120.0, help="seconds to wait for every agent [120]")
    p.add_argument("-v", "--verbose", action="store_true")
    add_config_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s ros2-bridge %(levelname)s %(message)s")
    try:
        scenario = load_scenario(args.config)
        keys = Keys(args.run_id)
        conf = dataclasses.replace(session_config_from_args(args), lease_ms=round(1e3 * scenario.run.lease_s))
        if not scenario.world.ros2:
            raise ConfigError(f"world.backend = {scenario.world.backend!r} is not allowed here; the ROS 2 bridge "
                              "runs scenarios with world.backend = 'ros2'")
        from copath.ros2 import missing  # noqa: PLC0415

        if (m := missing()) is not None:
            raise ConfigError(m)
        tasks = sim_tasks(scenario, args.tasks, None)
    except (ConfigError, ValueError) as exc:
        print(f"copath ros2-bridge: {exc}", file=sys.stderr)
        return 2
    from copath.wire.acl import AccessDenied, AccessPolicy  # noqa: PLC0415
    from copath.wire.session import ZenohLink  # noqa: PLC0415

    holder: dict[str, BridgeNode] = {}
    received: list[str] = []

    def _on_signal(signum, frame) -> None:
        node = holder.get("node")
        if node is not None:
            node.stop_robots()  # first: zero Twists out before anything else
        received.append(signal.Signals(signum).name)
        raise _Stop()

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    ok = False
    robots = None
    try:
        robots = Ros2Robots(scenario, lambda *a: holder["node"].on_pose(*a) if "node" in holder else None)
        with ZenohLink.open(conf) as link:
            node = BridgeNode(scenario, keys, link, robots.publish, args.start_timeout, tasks=tasks)
            holder["node"] = node
            try:
                if conf.authenticated:
                    link.guard(AccessPolicy.for_scenario(keys, scenario), "sim")
                ok = node.run()
            except AccessDenied as exc:
                print(f"copath ros2-bridge: {exc}", file=sys.stderr)
                return 2
            except _Stop:
                for s in old:  # a second signal during the wind-down does not interrupt it
                    signal.signal(s, signal.SIG_IGN)
                if not getattr(node, "_finished", False):
                    node._finish(node.k, f"stopped by {received[-1]} at t={node.world.t:.2f} s", False)
            finally:
                for s in old:
                    signal.signal(s, signal.SIG_IGN)
                node.hold_zeros()
                lat = sorted(node.latency_s)
                if lat:
                    logger.info("command latency (pose stamp -> cmd_vel publish): p50 %.1f ms, p99 %.1f ms, n=%d",
                                1e3 * lat[len(lat) // 2], 1e3 * lat[min(len(lat) - 1, int(0.99 * len(lat)))], len(lat))
            time.sleep(0.2)  # let the router forward the closing records before the session closes
    except _Stop:  # before the run was set up: nothing was commanded yet
        print(f"copath ros2-bridge: stopped by {received[-1]} before the run started", file=sys.stderr)
    finally:
        if robots is not None:
            robots.close()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
