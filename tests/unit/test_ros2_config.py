"""The ``[world]`` table (copath.ros2.config), frames, and a ROS 2 scenario without ROS 2."""

from __future__ import annotations

import math
import pathlib
import subprocess
import sys

import pytest

from copath.config import ConfigError
from copath.ros2 import frames
from copath.ros2.config import parse_world
from orchestrator import api

REPO = pathlib.Path(__file__).resolve().parents[2]
ROS2 = {"backend": "ros2"}
REALTIME = {"clock": "realtime"}


def test_default_world_is_the_simulator():
    s = api.load("e5.5", {})
    assert s.world.backend == "sim" and not s.world.ros2


def test_ros2_world_defaults_and_per_robot_topics():
    s = api.load("e5.5", {}).with_overrides(run=REALTIME, world={
        "backend": "ros2", "robots": {"r2": {"pose_type": "pose_stamped", "frame": "map", "origin": [1, 2, 0.5]},
                                       "r3": {"cmd_topic": "robot3/cmd"}}})
    io = s.world.robots
    assert io["r1"].pose_topic == "/r1/odom" and io["r1"].pose_type == "odometry" and io["r1"].cmd_topic == "/r1/cmd_vel"
    assert io["r1"].origin == s.robot("r1").pose  # odometry starts at zero where the robot starts
    assert io["r2"].pose_topic == "/r2/pose" and io["r2"].frame == "map" and io["r2"].origin == (1.0, 2.0, 0.5)
    assert io["r3"].cmd_topic == "/robot3/cmd"


def test_lockstep_is_refused_with_one_line():
    with pytest.raises(ConfigError) as exc:
        api.load("e5.5", {}).with_overrides(world=ROS2)
    assert exc.value.errors == ["run.clock = 'lockstep' is not allowed; world.backend = 'ros2' drives real robots "
                                "on the wall clock: set run.clock = 'realtime'"]


@pytest.mark.parametrize("world, key", [
    ({"backend": "gazebo"}, "world.backend"),
    ({"backend": "ros2", "robots": {"r9": {}}}, "world.robots.r9"),
    ({"backend": "ros2", "robots": {"r1": {"pose_type": "tf"}}}, "world.robots.r1.pose_type"),
    ({"backend": "ros2", "robots": {"r1": {"pose_topic": "/a b"}}}, "world.robots.r1.pose_topic"),
    ({"backend": "ros2", "robots": {"r1": {"cmd_topic": "/r2/cmd_vel"}}}, "world.robots"),
    ({"backend": "ros2", "robots": {"r1": {"speed": 1}}}, "world.robots.r1.speed"),
    ({"backend": "ros2", "start_timeout_s": 0}, "world.start_timeout_s"),
    ({"backend": "ros2", "robots": {"r1": {"origin": "here"}}}, "world.robots.r1.origin"),
    ({"backend": "ros2", "colour": "red"}, "world.colour"),
])
def test_bad_world_names_the_key(world, key):
    with pytest.raises(ConfigError) as exc:
        parse_world(world, {"r1": (0.0, 0.0, 0.0), "r2": (1.0, 0.0, 0.0)})
    assert str(exc.value).startswith(f"{key} = ")


def test_frames_round_trip_and_quaternions():
    origin = (1.0, -2.0, 0.7)
    for pose in [(0.0, 0.0, 0.0), (0.3, 1.2, -2.5), (-4.0, 0.1, 3.0)]:
        back = frames.from_scenario(origin, frames.to_scenario(origin, pose))
        assert back[:2] == pytest.approx(pose[:2], abs=1e-12)
        assert math.sin(back[2] - pose[2]) == pytest.approx(0.0, abs=1e-12)
        q = frames.quaternion_from_yaw(pose[2])
        assert frames.yaw_from_quaternion(*q) == pytest.approx(pose[2], abs=1e-12)
    assert frames.to_scenario(origin, (0.0, 0.0, 0.0)) == pytest.approx(origin)


def test_ros2_scenario_without_rclpy_gives_one_line_and_no_traceback():
    """ROS 2 missing (simulated by hiding rclpy): validation fails with one line saying what to install."""
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "from orchestrator.cli import main\n"
            "sys.exit(main(['run', 'e5.5', '--set', 'world.backend=ros2', '--clock', 'realtime']))")
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2, p.stderr
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "world.backend = 'ros2' needs ROS 2 for Python (" in lines[0] and "not installed)" in lines[0]
    assert "rclpy" in lines[0].split("needs ROS 2 for Python (", 1)[1].split(")", 1)[0]  # the hidden module named
    assert "pip install -e '.[ros2]'" in lines[0]


def test_ros2_view_flag_without_rclpy_gives_one_line():
    code = ("import sys; sys.modules['rclpy'] = None\n"
            "from orchestrator.cli import main\n"
            "sys.exit(main(['run', 'e5.5', '--ros2']))")
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert "--ros2 needs ROS 2 for Python (" in lines[0] and "not installed): pip install -e '.[ros2]'" in lines[0]
    assert "rclpy" in lines[0].split("needs ROS 2 for Python (", 1)[1].split(")", 1)[0]


def test_agent_ros2_io_outside_a_ros2_world_is_one_line():
    p = subprocess.run([sys.executable, "-m", "agent", "--run-id", "x", "--robot", "r1", "--config",
                        "configs/e5.5-column-lemniscate.toml", "--io", "ros2"], cwd=REPO, capture_output=True,
                       text=True, timeout=120)
    lines = [ln for ln in p.stderr.strip().splitlines() if " INFO " not in ln]  # the agent's start-up log line
    assert p.returncode == 2 and len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert lines[0].startswith("copath agent: ") and "--io ros2" in lines[0]
