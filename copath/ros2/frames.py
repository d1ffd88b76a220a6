"""Planar poses and ROS 2 frames (pure: numbers in, numbers out; docs/reference/ros2.md, "Frames").

ROS messages carry a 3-D pose with a quaternion; copath's robots live in the plane,
(x, y, theta) as in (3.1)/(3.3). A pose source reports poses in its own frame (a robot's
``odom``, a motion-capture ``map``); ``origin`` places that frame in the scenario's.
"""

from __future__ import annotations

import math

__all__ = ["yaw_from_quaternion", "quaternion_from_yaw", "compose", "to_scenario", "from_scenario"]


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Rotation about z of a unit quaternion [rad] (ZYX convention: the heading theta)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(theta: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation theta about z."""
    return 0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0)


def compose(a, b) -> tuple[float, float, float]:
    """a (+) b: pose b given in the frame whose pose is a."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1],
            math.atan2(math.sin(a[2] + b[2]), math.cos(a[2] + b[2])))


def to_scenario(origin, pose) -> tuple[float, float, float]:
    """A pose reported in the source frame, in the scenario's frame."""
    return compose(origin, pose)


def from_scenario(origin, pose) -> tuple[float, float, float]:
    """A pose of the scenario's frame, in the source frame (the inverse of :func:`to_scenario`)."""
    c, s = math.cos(origin[2]), math.sin(origin[2])
    dx, dy = pose[0] - origin[0], pose[1] - origin[1]
    th = pose[2] - origin[2]
    return c * dx + s * dy, -s * dx + c * dy, math.atan2(math.sin(th), math.cos(th))
