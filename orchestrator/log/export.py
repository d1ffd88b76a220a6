"""``copath export --ros2 RUN.mcap OUT.mcap``: a run as a ROS 2 bag (docs/reference/ros2.md, "Bags").

The bag is MCAP with ``cdr`` message encoding and ``ros2msg`` schemas, the format
``ros2 bag record -s mcap`` writes, so ``ros2 bag play``, RViz2, Foxglove, ``rosbags`` and
``mcap-ros2-support`` read it. CDR is written by ``mcap-ros2-support``; the message
definitions come from ``rosbags``' type store (ROS 2 Kilted), so nothing is hand-serialised.

=======================  ======================  ===========================================
topic                    type                    content
=======================  ======================  ===========================================
``/<robot>/odom``        nav_msgs/Odometry       world record pose (frame ``map``, child
                                                 ``<robot>/base_link``) and applied command
``/tf``                  tf2_msgs/TFMessage      ``map`` -> ``<robot>/base_link`` of every robot
``/<robot>/plan``        nav_msgs/Path           the horizon the robot's controller broadcasts
                                                 (DMPC assumed trajectory, leader plan, or a
                                                 ``plan`` in its telemetry), when it has one
``/paths/<name>``        nav_msgs/Path           each reference path of the scenario (once)
=======================  ======================  ===========================================

Times: a record at run time t (simulated time, the world record's ``t``) is written at
log time ``t0 + t`` and stamped so, where t0 is the run's first recorded log time: a
lockstep run plays back at its simulated pace.
"""

from __future__ import annotations

import json
import pathlib
import time
from typing import Any

import numpy as np

from copath.ros2.frames import quaternion_from_yaw
from copath.scenario import parse_scenario
from copath.wire.keys import Keys
from copath.wire.messages import PeerEnvelope, Telemetry, Truth, WireError, unpack

from orchestrator.log.mcap import iter_raw, read_metadata
from orchestrator.log.plans import plan_positions

__all__ = ["export_ros2", "RosTopics", "MAP_FRAME"]

MAP_FRAME = "map"
TYPES = ("nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage", "nav_msgs/msg/Path")


def _missing_libraries() -> str | None:
    for mod, dist in (("mcap_ros2", "mcap-ros2-support"), ("rosbags", "rosbags")):
        try:
            __import__(mod)
        except ImportError:
            return f"copath export --ros2 needs {dist}: pip install -e '.[ros2]'"
    return None


def _stamp(t: float) -> dict[str, int]:
    sec = int(np.floor(t))
    return {"sec": sec, "nanosec": min(999_999_999, int(round((t - sec) * 1e9)))}


def _pose(x: float, y: float, th: float) -> dict[str, Any]:
    qx, qy, qz, qw = quaternion_from_yaw(th)
    return {"position": {"x": float(x), "y": float(y), "z": 0.0}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def _path_msg(stamp: dict, xy: np.ndarray) -> dict[str, Any]:
    xy = np.asarray(xy, dtype=float)
    th = np.arctan2(np.gradient(xy[:, 1]), np.gradient(xy[:, 0])) if len(xy) > 1 else np.zeros(len(xy))
    header = {"stamp": stamp, "frame_id": MAP_FRAME}
    return {"header": header, "poses": [{"header": header, "pose": _pose(p[0], p[1], a)} for p, a in zip(xy, th)]}


class RosTopics:
    """A run's records as ROS 2 messages (plain dicts, by type name): the one mapping that
    ``copath export --ros2`` writes to a bag and ``copath run --ros2`` publishes live
    (orchestrator/view/ros2.py). Times are run times [s]; ``base`` is added to stamps."""

    def __init__(self, scenario, keys: Keys, base: float = 0.0) -> None:
        self.keys = keys
        self.base = base
        self.scenario = scenario
        self.plans: dict[str, np.ndarray] = {}
        self.version: dict[str, int] = {}  # per robot: plans received / plans written
        self.sent_plan: dict[str, int] = {}
        self._paths = {r.name: scenario.paths.get(r.path) if r.path else None for r in scenario.robots}

    def reference_paths(self) -> list[tuple[str, str, dict, float]]:
        out = []
        for name, path in self.scenario.paths.items():
            s = np.linspace(0.0, path.length, max(50, int(path.length / 0.05)))
            out.append((f"/paths/{name}", "nav_msgs/msg/Path", _path_msg(_stamp(self.base), path.pos(s)), 0.0))
        return out

    def feed(self, key: str, rec: Any) -> list[tuple[str, str, dict, float]]:
        """(topic, type, message, run time) of the messages ``rec`` gives rise to."""
        if isinstance(rec, PeerEnvelope):
            plan = plan_positions(self._paths.get(rec.sender), rec)
            if plan is not None:
                self.plans[rec.sender] = plan
                self.version[rec.sender] = self.version.get(rec.sender, 0) + 1
        elif isinstance(rec, Telemetry):
            plan = rec.data.get("plan")
            if isinstance(plan, list) and plan and all(isinstance(q, list) and len(q) >= 2 for q in plan):
                n = self.keys.relative(key).split("/")[1]
                self.plans[n] = np.asarray([q[:2] for q in plan], dtype=float)
                self.version[n] = self.version.get(n, 0) + 1
        elif isinstance(rec, Truth):
            return self._tick(rec)
        return []

    def _tick(self, rec: Truth) -> list[tuple[str, str, dict, float]]:
        out = []
        stamp = _stamp(self.base + rec.t)
        tfs = []
        for n, p, u in zip(rec.names, rec.poses, rec.commands):
            body = (u[0], u[1], u[2]) if len(u) == 3 else (u[0], 0.0, u[1])
            child = f"{n}/base_link"
            out.append((f"/{n}/odom", "nav_msgs/msg/Odometry", {
                "header": {"stamp": stamp, "frame_id": MAP_FRAME}, "child_frame_id": child,
                "pose": {"pose": _pose(*p[:3]), "covariance": [0.0] * 36},
                "twist": {"twist": {"linear": {"x": float(body[0]), "y": float(body[1]), "z": 0.0},
                                    "angular": {"x": 0.0, "y": 0.0, "z": float(body[2])}},
                          "covariance": [0.0] * 36}}, rec.t))
            q = quaternion_from_yaw(p[2])
            tfs.append({"header": {"stamp": stamp, "frame_id": MAP_FRAME}, "child_frame_id": child,
                        "transform": {"translation": {"x": float(p[0]), "y": float(p[1]), "z": 0.0},
                                      "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}}})
            plan = self.plans.get(n)
            if plan is not None and self.sent_plan.get(n) != self.version.get(n) and len(plan) > 1:
                out.append((f"/{n}/plan", "nav_msgs/msg/Path", _path_msg(stamp, plan), rec.t))
                self.sent_plan[n] = self.version[n]
        out.append(("/tf", "tf2_msgs/msg/TFMessage", {"transforms": tfs}, rec.t))
        return out


def export_ros2(run_mcap: str | pathlib.Path, out_mcap: str | pathlib.Path) -> dict[str, Any]:
    """Write the run ``run_mcap`` as a ROS 2 bag ``out_mcap``; returns messages per topic,
    the total and the rate (messages per second of export, reading the run included)."""
    problem = _missing_libraries()
    if problem:
        raise RuntimeError(problem)
    from mcap_ros2.writer import Writer  # noqa: PLC0415
    from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

    wall0 = time.perf_counter()
    meta = read_metadata(run_mcap)
    raw = json.loads(meta["scenario"]["json"])
    scenario = parse_scenario(raw, base_dir=None, source=str(raw.get("_source", "")))
    keys = Keys(meta["copath"]["run_id"])
    store = get_typestore(Stores.ROS2_KILTED)
    counts: dict[str, int] = {}
    # only the records the topics come from are decoded (not observations, commands, ...)
    records = []
    t0_ns = None
    for t, key, data in iter_raw(run_mcap):
        t0_ns = t if t0_ns is None else min(t0_ns, t)
        rel = keys.relative(key)
        if rel == "sim/truth" or rel.endswith("/telemetry") or rel.startswith("peer/"):
            try:
                records.append((key, unpack(data)))
            except WireError:
                continue
    t0_ns = t0_ns or 0
    topics = RosTopics(scenario, keys, base=t0_ns * 1e-9)
    with open(out_mcap, "wb") as fh:
        writer = Writer(fh)
        schemas = {name: writer.register_msgdef(name, store.generate_msgdef(name, ros_version=2)[0]) for name in TYPES}

        def put(msgs) -> None:
            for topic, typ, msg, t in msgs:
                ns = t0_ns + int(round(t * 1e9))
                writer.write_message(topic, schemas[typ], msg, log_time=ns, publish_time=ns,
                                     sequence=counts.get(topic, 0))
                counts[topic] = counts.get(topic, 0) + 1

        put(topics.reference_paths())
        for key, rec in records:
            put(topics.feed(key, rec))
        writer.finish()
    wall = time.perf_counter() - wall0
    total = sum(counts.values())
    return {"topics": dict(sorted(counts.items())), "messages": total, "wall_s": round(wall, 3),
            "rate_msg_per_s": round(total / wall, 1) if wall > 0 else None}
