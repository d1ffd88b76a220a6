"""Simulated ROS 2 robots for people who have none (docs/reference/ros2.md, "Robots without robots").

One process, one or more robots of a scenario, each behaving like a ROS 2 driver:
it takes geometry_msgs/Twist on ``/<robot>/cmd_vel`` and publishes its pose on
``/<robot>/odom`` (nav_msgs/Odometry, frame ``<robot>/odom``, child ``<robot>/base_link``)
or, for a robot whose ``[world.robots.NAME] pose_type = "pose_stamped"``, on
``/<robot>/pose`` (geometry_msgs/PoseStamped, frame ``map``), as the scenario's
``[world]`` table says. What makes it a robot rather than the simulator:

- the model's velocity limits are the hardware's ((3.2) wheel speeds, Sec. 5.5.3);
- motor lag: each body velocity follows its command through a first-order lag
  (``--lag-s``);
- odometry latency and noise: a pose is measured at a physics step, stamped then, and
  published ``--latency-s`` later with Gaussian noise (``--noise``);
- a command watchdog: no Twist for ``--watchdog-s`` and the robot stops on its own;
- odometry starts at zero where the robot starts (the scenario's start pose), as wheel
  odometry does; the scenario's default ``origin = "start"`` maps it back.

Usage (two terminals; docs/reference/ros2.md)::

    python examples/ros2_robots/ros2_robots.py e5.5
    copath run e5.5 --set world.backend=ros2 --clock realtime

``--robots r1,r2`` runs a subset (one process per robot, as on real robots);
``--record FILE`` writes every Twist received, with its arrival time, as JSON lines;
``--stop-odom NAME@S`` stops a robot's odometry S seconds after its first command (a
failing sensor, for tests and demonstrations).
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import math
import signal
import sys
import threading
import time

import numpy as np

logger = logging.getLogger("ros2_robots")


class Robot:
    """One simulated robot: true pose, lagged body velocity, delayed noisy odometry."""

    def __init__(self, name: str, model, pose, io, lag_s: float, rng) -> None:
        self.name = name
        self.model = model
        self.io = io
        self.omni = model.kind == "omni"
        self.pose = np.array(pose, dtype=float)
        self.cmd = np.zeros(model.command_size)
        self.vel = np.zeros(model.command_size)
        self.lag_s = lag_s
        self.rng = rng
        self.cmd_at = time.monotonic()
        self.first_cmd_at: float | None = None
        self.watchdog_stops = 0
        self.pending: collections.deque = collections.deque()  # (publish at, stamp, reported pose)

    def command(self, cmd) -> None:
        self.cmd, _ = self.model.saturate(cmd)  # the hardware's limits
        self.cmd_at = time.monotonic()
        if self.first_cmd_at is None and np.any(np.abs(self.cmd) > 0):
            self.first_cmd_at = self.cmd_at

    def step(self, dt: float, watchdog_s: float) -> None:
        if watchdog_s > 0 and time.monotonic() - self.cmd_at > watchdog_s and np.any(self.cmd != 0):
            logger.warning("%s: no command for %.2f s; stopping (watchdog)", self.name, watchdog_s)
            self.cmd = np.zeros_like(self.cmd)
            self.watchdog_stops += 1
        a = 1.0 - math.exp(-dt / self.lag_s) if self.lag_s > 0 else 1.0
        self.vel += a * (self.cmd - self.vel)
        self.pose = self.model.step(self.pose, self.vel, dt)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="ros2_robots", description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="scenario file, bundled file stem or experiment id (e.g. e5.5)")
    p.add_argument("--robots", help="comma-separated robot names to run [all of the scenario's]")
    p.add_argument("--physics-hz", type=float, default=100.0, help="integration rate [100]")
    p.add_argument("--odom-hz", type=float, default=30.0, help="odometry rate [30]")
    p.add_argument("--lag-s", type=float, default=0.1, help="motor time constant [0.1 s]")
    p.add_argument("--latency-s", type=float, default=0.02, help="odometry latency [0.02 s]")
    p.add_argument("--noise", default="0.002,0.002,0.004", help="odometry noise std x,y,theta [m,m,rad]")
    p.add_argument("--watchdog-s", type=float, default=0.5, help="stop without a command for this long [0.5 s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--record", help="write every Twist received as a JSON line to this file")
    p.add_argument("--stop-odom", action="append", default=[], metavar="NAME@S",
                   help="stop NAME's odometry S seconds after its first command")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s ros2_robots %(levelname)s %(message)s")

    from copath.ros2 import frames, io, missing
    from copath.ros2.config import parse_world
    from orchestrator import api

    if (m := missing("examples/ros2_robots")) is not None:
        print(f"ros2_robots: {m}", file=sys.stderr)
        return 2
    try:
        scenario = api.load(args.config, {})
        noise = np.array([float(v) for v in args.noise.split(",")], dtype=float).reshape(3)
        names = args.robots.split(",") if args.robots else list(scenario.robot_names)
        for n in names:
            scenario.robot(n)
        stops = {}
        for s in args.stop_odom:
            n, _, sec = s.partition("@")
            scenario.robot(n)
            stops[n] = float(sec)
    except ValueError as exc:
        print(f"ros2_robots: {exc}", file=sys.stderr)
        return 2
    world = (scenario.world if scenario.world.ros2
             else parse_world({"backend": "ros2"}, {r.name: r.pose for r in scenario.robots}))
    from geometry_msgs.msg import Twist
    from nav_msgs.msg import Odometry
    from geometry_msgs.msg import PoseStamped

    spin = io.Spinner("copath_example_robots")
    node = spin.node
    rng = np.random.default_rng(args.seed)
    robots: dict[str, Robot] = {}
    pubs = {}
    lock = threading.Lock()
    record = open(args.record, "a", buffering=1) if args.record else None

    for name in names:
        spec = scenario.robot(name)
        rio = world.robots[name]
        r = robots[name] = Robot(name, spec.model, spec.pose, rio, args.lag_s, rng)
        odom = rio.pose_type == "odometry"
        pubs[name] = node.create_publisher(Odometry if odom else PoseStamped, rio.pose_topic, 10)

        def on_cmd(msg, r=r):
            cmd = io.command_of(msg, r.omni)
            with lock:
                r.command(cmd)
            if record is not None:
                record.write(json.dumps({"t": time.time(), "robot": r.name, "cmd": list(cmd)}) + "\n")

        node.create_subscription(Twist, rio.cmd_topic, on_cmd, io.qos_cmd())
        logger.info("%s (%s): pose on %s (%s), commands on %s", name, spec.model.kind, rio.pose_topic,
                    rio.pose_type, rio.cmd_topic)
    spin.start()
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    dt = 1.0 / args.physics_hz
    odom_every = max(1, round(args.physics_hz / args.odom_hz))
    i = 0
    next_t = last = time.monotonic()
    try:
        while not stop.is_set():
            now_wall, now = time.time(), time.monotonic()
            step, last = min(0.1, now - last), now  # the time that really passed (a busy machine is late)
            with lock:
                for r in robots.values():
                    r.step(step, args.watchdog_s)
                    if i % odom_every:
                        continue
                    if r.name in stops and r.first_cmd_at is not None and time.monotonic() - r.first_cmd_at > stops[r.name]:
                        if stops[r.name] >= 0:
                            logger.warning("%s: odometry stopped (--stop-odom)", r.name)
                            stops[r.name] = -1.0
                        continue
                    reported = frames.from_scenario(r.io.origin, r.pose) + rng.normal(0.0, 1.0, 3) * noise
                    r.pending.append((time.monotonic() + args.latency_s, now_wall, reported, r.vel.copy()))
            for r in robots.values():  # publish what is due (measured latency_s ago)
                while r.pending and r.pending[0][0] <= time.monotonic():
                    _, stamp, pose, vel = r.pending.popleft()
                    if r.io.pose_type == "odometry":
                        body = (vel[0], vel[1] if r.omni else 0.0, vel[-1])
                        msg = io.odometry(stamp, r.io.frame or f"{r.name}/odom", f"{r.name}/base_link", pose, body)
                    else:
                        msg = io.pose_stamped(stamp, r.io.frame or "map", pose)
                    pubs[r.name].publish(msg)
            i += 1
            next_t += dt
            sleep = next_t - time.monotonic()
            if sleep > 0:
                stop.wait(sleep)
            else:
                next_t = time.monotonic()
    finally:
        spin.close()
        if record is not None:
            record.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
