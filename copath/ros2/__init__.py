"""ROS 2 worlds and views of a copath run (docs/reference/ros2.md).

This package is importable without ROS 2: :mod:`copath.ros2.config` (the ``[world]``
table) and :mod:`copath.ros2.frames` (pose and frame conversions) are pure.
:mod:`copath.ros2.io` imports ``rclpy`` inside its functions only, so a copath without
the ``ros2`` extra never loads it; :func:`missing` tells, in one line, what to install.
"""

from __future__ import annotations

import importlib.util

__all__ = ["missing", "INSTALL_HINT", "REQUIRED_MODULES"]

REQUIRED_MODULES = ("rclpy", "geometry_msgs", "nav_msgs", "std_msgs", "rmw_fastrtps_cpp")
"""Python modules (or, for the middleware, ament packages) a ROS 2 world needs."""

INSTALL_HINT = "pip install -e '.[ros2]'  (or: pip install 'copath[ros2]')"


def _present(module: str) -> bool:
    if module == "rmw_fastrtps_cpp":  # a C++ library: its wheel registers the ament package
        try:
            from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

            version("ros-rmw-fastrtps-cpp")
            return True
        except PackageNotFoundError:
            return False
    try:
        return importlib.util.find_spec(module) is not None
    except (ValueError, ImportError):  # sys.modules[module] is None: hidden on purpose
        return False


def missing(what: str = "world.backend = 'ros2'") -> str | None:
    """None when ROS 2 for Python is installed, else one line naming what is missing and
    how to install it (``what`` says who needs it)."""
    gone = [m for m in REQUIRED_MODULES if not _present(m)]
    if not gone:
        return None
    return f"{what} needs ROS 2 for Python ({', '.join(gone)} not installed): {INSTALL_HINT}"
