"""``copath run ... --ros2``: a simulated run mirrored into ROS 2 live (docs/reference/ros2.md, "Live view").

The orchestrator hands every record its router receives to :meth:`Ros2Mirror.write`
(as it hands them to the recorder); a thread of its own decodes them and publishes the
topics of ``copath export --ros2`` (:class:`orchestrator.log.export.RosTopics`, one mapping
for both) with rclpy, so RViz2, rqt and ``ros2 topic echo`` see the fleet:
``/<robot>/odom``, ``/<robot>/plan``, ``/paths/<name>`` (transient local: a viewer
started later still gets them) and ``/tf`` where ``tf2_msgs`` is installed (it is not
among the PyPI wheels; the bag export has it).

The recorder never waits for ROS 2: records queue up to ``QUEUE`` and the rest are
dropped and counted (``dropped``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from copath.wire.keys import Keys
from copath.wire.messages import PeerEnvelope, Telemetry, Truth, WireError, unpack

from orchestrator.log.export import RosTopics

logger = logging.getLogger(__name__)

__all__ = ["Ros2Mirror", "fill"]

QUEUE = 10_000


def fill(msg: Any, d: dict) -> Any:
    """Set the fields of an rclpy message from a plain dict (nested dicts, lists of dicts
    for sequences of messages, lists of numbers for arrays)."""
    types = msg.get_fields_and_field_types()
    for k, v in d.items():
        if isinstance(v, dict):
            fill(getattr(msg, k), v)
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            elem = types[k]
            elem = elem[elem.index("<") + 1: elem.rindex(">")] if "<" in elem else elem.rstrip("[]")
            pkg, name = elem.split("/")
            mod = __import__(f"{pkg}.msg", fromlist=[name])
            setattr(msg, k, [fill(getattr(mod, name)(), e) for e in v])
        else:
            setattr(msg, k, v)
    return msg


class Ros2Mirror:
    """Publish a run's records on ROS 2 as they arrive (one node, one thread)."""

    def __init__(self, scenario, keys: Keys) -> None:
        from nav_msgs.msg import Odometry, Path  # noqa: PLC0415

        from copath.ros2 import io  # noqa: PLC0415

        self.keys = keys
        self.topics = RosTopics(scenario, keys, base=time.time())
        self.spin = io.Spinner("copath_view")
        node = self.spin.node
        self.cls = {"nav_msgs/msg/Odometry": Odometry, "nav_msgs/msg/Path": Path}
        try:
            from tf2_msgs.msg import TFMessage  # noqa: PLC0415

            self.cls["tf2_msgs/msg/TFMessage"] = TFMessage
        except ImportError:
            logger.info("tf2_msgs is not installed: the ROS 2 view has no /tf (the bag export has it)")
        self.pubs: dict[str, Any] = {}
        self._node, self._io = node, io
        self.q: queue.Queue = queue.Queue(maxsize=QUEUE)
        self.dropped = 0
        self.published = 0
        for topic, typ, msg, _ in self.topics.reference_paths():
            self._publish(topic, typ, msg, latched=True)
        # every robot's odometry publisher from the start, not at its first message: a
        # subscriber discovers it while the fleet starts, and sees the run from its first
        # tick (made at the first truth, the publishers of a fast lockstep run were matched
        # a second or more into it, and what came before was lost)
        for name in scenario.robot_names:
            self._publisher(f"/{name}/odom", "nav_msgs/msg/Odometry")
        self._thread = threading.Thread(target=self._loop, name="ros2-view", daemon=True)
        self.spin.start()
        self._thread.start()

    def _publisher(self, topic: str, typ: str, latched: bool = False) -> Any:
        """The publisher of ``topic`` (made at its first use), or None for a type not installed."""
        pub = self.pubs.get(topic)
        if pub is None:
            cls = self.cls.get(typ)
            if cls is None:
                return None
            qos = self._io.qos_latched() if latched or topic.endswith("/plan") else self._io.qos_view()
            pub = self.pubs[topic] = self._node.create_publisher(cls, topic, qos)
        return pub

    def _publish(self, topic: str, typ: str, msg: dict, latched: bool = False) -> None:
        pub = self._publisher(topic, typ, latched)
        if pub is None:
            return
        pub.publish(fill(self.cls[typ](), msg))
        self.published += 1

    def write(self, key: str, data: bytes) -> None:
        """A record the router received (Zenoh's thread): queued, never waited for."""
        rel = self.keys.relative(key)
        if not (rel == "sim/truth" or rel.endswith("/telemetry") or rel.startswith("peer/")):
            return
        try:
            self.q.put_nowait((key, data))
        except queue.Full:
            self.dropped += 1

    def _loop(self) -> None:
        while True:
            item = self.q.get()
            if item is None:
                return
            key, data = item
            try:
                rec = unpack(data)
            except WireError:
                continue
            if not isinstance(rec, (Truth, Telemetry, PeerEnvelope)):
                continue
            try:
                for topic, typ, msg, _ in self.topics.feed(key, rec):
                    self._publish(topic, typ, msg)
            except Exception:  # noqa: BLE001  (a view must never stop a run)
                logger.exception("ROS 2 view: could not publish a record of %s", key)

    def close(self) -> None:
        try:
            self.q.put(None, timeout=2.0)
        except queue.Full:
            pass
        self._thread.join(timeout=5.0)
        self.spin.close()
        if self.dropped:
            logger.warning("ROS 2 view: %d records dropped (ROS 2 publishing fell behind)", self.dropped)
