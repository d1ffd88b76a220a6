"""ROS 2 message and QoS helpers (rclpy is imported inside each function, never at import).

The one place that says which QoS copath uses on ROS 2 (docs/reference/ros2.md, "QoS"):

- poses (nav_msgs/Odometry, geometry_msgs/PoseStamped) are *subscribed* best effort,
  keep last 5, volatile: the sensor-data profile, which matches both reliable and
  best-effort publishers, so every driver's odometry is heard;
- commands (geometry_msgs/Twist) are *published* reliable, keep last 10, volatile: a
  reliable publisher matches both reliable and best-effort subscribers, and the TurtleBot,
  Nav2 and ros2_control drivers subscribe reliable or best effort;
- what a view of a run publishes is reliable, keep last 10 (paths: transient local,
  so RViz2 started later still sees them).
"""

from __future__ import annotations

import math
import os
from typing import Any

from .frames import quaternion_from_yaw, yaw_from_quaternion

__all__ = ["init", "Spinner", "domain_id", "qos_pose", "qos_cmd", "qos_view", "qos_latched", "pose_of", "stamp_of", "twist",
           "command_of", "odometry", "pose_stamped", "set_stamp", "ZERO"]

ZERO = (0.0, 0.0, 0.0)


def init() -> None:
    """Initialise rclpy for this process (``ROS_DOMAIN_ID`` from the environment is
    respected by rclpy itself). rclpy's own signal handlers are not installed: the
    caller's SIGINT/SIGTERM handling stops the robots first (docs/reference/ros2.md, zero on exit)."""
    import rclpy  # noqa: PLC0415
    from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

    if not rclpy.ok():
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)


class Spinner:
    """One rclpy node spun by a daemon thread (callbacks run there); :meth:`close` stops
    it and shuts rclpy down."""

    def __init__(self, name: str) -> None:
        import threading  # noqa: PLC0415

        import rclpy  # noqa: PLC0415
        from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

        init()
        self.node = rclpy.create_node(name)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, name=f"{name}-spin", daemon=True)

    def start(self) -> "Spinner":
        self.thread.start()
        return self

    def _spin(self) -> None:
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001  (shutting down under our feet)
                if self._stop.is_set():
                    return
                raise

    def close(self) -> None:
        import rclpy  # noqa: PLC0415

        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout=2.0)
        try:
            self.executor.shutdown(timeout_sec=0.5)
            self.node.destroy_node()
        finally:
            if rclpy.ok():
                rclpy.shutdown()


def domain_id() -> int:
    """The ROS 2 domain of this process (``ROS_DOMAIN_ID``, default 0)."""
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)
    except ValueError:
        return 0


def qos_pose():
    from rclpy.qos import qos_profile_sensor_data  # noqa: PLC0415

    return qos_profile_sensor_data


def qos_cmd():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def qos_view():
    return qos_cmd()


def qos_latched():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def pose_of(msg: Any) -> tuple[float, float, float]:
    """(x, y, theta) of an Odometry's or a PoseStamped's pose, in its header's frame."""
    p = msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose
    q = p.orientation
    return float(p.position.x), float(p.position.y), yaw_from_quaternion(q.x, q.y, q.z, q.w)


def stamp_of(msg: Any) -> float:
    """The header stamp [s since the epoch on the sender's clock]."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def set_stamp(header: Any, t: float, frame: str) -> None:
    sec = math.floor(t)
    header.stamp.sec = int(sec)
    header.stamp.nanosec = min(999_999_999, int(round((t - sec) * 1e9)))
    header.frame_id = frame


def twist(cmd, omni: bool):
    """geometry_msgs/Twist of a body command: unicycle (v, omega) -> linear.x, angular.z;
    omni (u, v, omega) -> linear.x, linear.y, angular.z."""
    from geometry_msgs.msg import Twist  # noqa: PLC0415

    m = Twist()
    m.linear.x = float(cmd[0])
    if omni:
        m.linear.y = float(cmd[1])
    m.angular.z = float(cmd[-1])
    return m


def command_of(msg: Any, omni: bool) -> tuple[float, ...]:
    """The body command a Twist carries (inverse of :func:`twist`)."""
    if omni:
        return float(msg.linear.x), float(msg.linear.y), float(msg.angular.z)
    return float(msg.linear.x), float(msg.angular.z)


def odometry(t: float, frame: str, child: str, pose, vel=None):
    """nav_msgs/Odometry at time t: pose (x, y, theta) in ``frame``, body velocity
    (u, v, omega) in ``child``."""
    from nav_msgs.msg import Odometry  # noqa: PLC0415

    m = Odometry()
    set_stamp(m.header, t, frame)
    m.child_frame_id = child
    m.pose.pose.position.x, m.pose.pose.position.y = float(pose[0]), float(pose[1])
    qx, qy, qz, qw = quaternion_from_yaw(float(pose[2]))
    o = m.pose.pose.orientation
    o.x, o.y, o.z, o.w = qx, qy, qz, qw
    if vel is not None:
        m.twist.twist.linear.x, m.twist.twist.linear.y = float(vel[0]), float(vel[1])
        m.twist.twist.angular.z = float(vel[2])
    return m


def pose_stamped(t: float, frame: str, pose):
    from geometry_msgs.msg import PoseStamped  # noqa: PLC0415

    m = PoseStamped()
    set_stamp(m.header, t, frame)
    m.pose.position.x, m.pose.position.y = float(pose[0]), float(pose[1])
    qx, qy, qz, qw = quaternion_from_yaw(float(pose[2]))
    o = m.pose.orientation
    o.x, o.y, o.z, o.w = qx, qy, qz, qw
    return m
