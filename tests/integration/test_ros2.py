"""ROS 2 worlds (docs/reference/ros2.md): copath runs driving simulated ROS 2 robots
(examples/ros2_robots) through the bridge, over Fast DDS and Zenoh.

Each test has its own ROS_DOMAIN_ID and keeps discovery on this host, and stops every
process it started by pid (``procs``). Skipped, with the reason, where ROS 2 for Python
(the ``ros2`` extra) is missing.
"""

from __future__ import annotations

import json
import os
import pathlib
import signal
import time

import pytest

from copath.ros2 import missing
from orchestrator.log.mcap import read_log

pytestmark = [pytest.mark.fleet, pytest.mark.skipif(missing() is not None, reason=str(missing()))]

ROBOTS = "examples/ros2_robots/ros2_robots.py"
ROS2 = ["--set", "world.backend=ros2", "--clock", "realtime"]


@pytest.fixture
def ros_env(monkeypatch, tmp_path):
    """A ROS 2 domain of this test's own, discovery on this host only."""
    domain = 1 + (os.getpid() + int(time.time() * 1000)) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return domain


def _robots(procs, config: str, names: list[str] | None, record: pathlib.Path, *extra: str):
    """One robot process per name (as on real robots), every Twist they receive recorded."""
    out = []
    for name in names or [None]:
        argv = [ROBOTS, config, "--record", str(record), *extra]
        if name is not None:
            argv += ["--robots", name]
        out.append(procs.start(argv))
    return out


def _run(procs, config: str, out: pathlib.Path, *extra: str):
    return procs.start(["-m", "orchestrator", "run", config, *ROS2, "--out", str(out), "-q", "--no-plots", *extra])


def _twists(record: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in record.read_text().splitlines() if line.strip()]


def _events(mcap: pathlib.Path, what: str) -> list:
    return [r for _, _, r in read_log(mcap).records if getattr(r, "TYPE", "") == "event" and r.what == what]


def _stats(mcap: pathlib.Path, proc: str) -> dict:
    return next(r.counters for _, _, r in read_log(mcap).records if getattr(r, "TYPE", "") == "stats" and r.proc == proc)


def test_e55_column_over_three_ros2_robots(procs, ros_env, tmp_path):
    """E5.5 (Sec. 5.5.4): three ROS 2 robot processes, graded from the log's reported poses."""
    record = tmp_path / "twists.jsonl"
    _robots(procs, "e5.5", ["r1", "r2", "r3"], record)
    out = tmp_path / "run"
    run = _run(procs, "e5.5", out, "--duration", "45", "--set", "run.settle_s=30")
    _, err = run.communicate(timeout=400)
    assert run.returncode in (0, 3), err.decode()[-2000:]  # 3: a stricter [targets] bound missed
    m = json.loads((out / "metrics.json").read_text())
    assert m["fleet"]["coordination_error_max_m"] < 0.05, m["fleet"]
    assert m["fleet"]["collisions"] == 0
    world = _events(out / "run.mcap", "world")
    assert world and world[0].detail["poses"].startswith("reported by the robots")
    st = _stats(out / "run.mcap", "sim")
    assert st["world"] == "ros2" and set(st["poses"]) == {"r1", "r2", "r3"} and min(st["poses"].values()) > 100
    assert st["cmd_latency_samples"] > 100 and st["cmd_latency_ms_p50"] is not None
    tw = _twists(record)
    assert {t["robot"] for t in tw} == {"r1", "r2", "r3"}
    assert all(len(t["cmd"]) == 2 for t in tw)  # unicycles: linear.x, angular.z


def test_omni_chapter4_over_a_ros2_robot(procs, ros_env, tmp_path):
    """E4.2 (Sec. 4.2.3): an omni robot's NMPC drives a ROS 2 omni robot (linear.y used)."""
    record = tmp_path / "twists.jsonl"
    _robots(procs, "e4.2", None, record)
    out = tmp_path / "run"
    run = _run(procs, "e4.2", out, "--duration", "16")
    _, err = run.communicate(timeout=300)
    assert run.returncode in (0, 3), err.decode()[-2000:]
    r1 = json.loads((out / "metrics.json").read_text())["robots"]["r1"]
    assert r1["path_error_max_m"] < 0.3  # Sec. 4.2.3 reports < 0.3 m; lag and latency cost some
    assert r1["limit_violations"] == 0
    tw = _twists(record)
    assert all(len(t["cmd"]) == 3 for t in tw) and any(abs(t["cmd"][1]) > 0.05 for t in tw)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_interrupted_run_stops_every_robot_within_100_ms(procs, ros_env, tmp_path, sig):
    """Ctrl-C or SIGTERM to `copath run`: every robot receives a zero Twist within 100 ms
    and zeros for half a second after."""
    record = tmp_path / "twists.jsonl"
    _robots(procs, "e5.5", None, record)
    out = tmp_path / "run"
    run = _run(procs, "e5.5", out)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline:  # under way: every robot is moving
        if record.exists() and {t["robot"] for t in _twists(record) if any(t["cmd"])} == {"r1", "r2", "r3"}:
            break
        assert run.poll() is None, run.communicate()[1].decode()[-2000:]
        time.sleep(0.2)
    time.sleep(1.0)
    t_sig = time.time()
    os.kill(run.pid, sig)
    run.communicate(timeout=60)
    assert run.returncode != 0
    time.sleep(0.3)
    tw = [t for t in _twists(record) if t["t"] >= t_sig]
    for name in ("r1", "r2", "r3"):
        mine = [t for t in tw if t["robot"] == name]
        first_zero = next(t["t"] for t in mine if not any(t["cmd"]))
        assert first_zero - t_sig < 0.1, (name, first_zero - t_sig)
        after = [t for t in mine if t["t"] >= first_zero]
        assert all(not any(t["cmd"]) for t in after), name  # nothing moves it again
        assert after[-1]["t"] - first_zero >= 0.45 and len(after) >= 10, (name, len(after))


@pytest.mark.parametrize("policy", ["fail", "continue"])
def test_robot_whose_odometry_stops_is_lost(procs, ros_env, tmp_path, policy):
    """r2's odometry stops 3 s after its first command: after run.lease_s it is lost, held at
    zero, and run.on_robot_failure applies."""
    record = tmp_path / "twists.jsonl"
    _robots(procs, "e5.5", None, record, "--stop-odom", "r2@3")
    out = tmp_path / "run"
    run = _run(procs, "e5.5", out, "--duration", "12", "--set", "run.settle_s=5", "--on-robot-failure", policy)
    _, err = run.communicate(timeout=300)
    err = err.decode()
    if policy == "fail":
        assert run.returncode == 1, err[-2000:]
        assert "robot r2 lost: no pose on /r2/odom" in err
    else:
        assert run.returncode in (0, 3), err[-2000:]
        lost = _events(out / "run.mcap", "robot_lost")
        assert [(e.detail["robot"], e.detail["cause"]) for e in lost] == [("r2", "pose")]
        assert _stats(out / "run.mcap", "sim")["pose_lost"] == ["r2"]
    # r2 was stopped when its pose stopped, while the run was still on
    end = max(t["t"] for t in _twists(record))
    r2 = [t for t in _twists(record) if t["robot"] == "r2"]
    zero_from = next(t["t"] for t in r2 if t["t"] > r2[0]["t"] + 3 and not any(t["cmd"]))
    assert all(not any(t["cmd"]) for t in r2 if t["t"] >= zero_from)
    if policy == "continue":
        r1_moving = [t for t in _twists(record) if t["robot"] == "r1" and t["t"] > zero_from + 1 and any(t["cmd"])]
        assert r1_moving and end - zero_from > 3  # the others went on without r2


def test_silent_topics_are_named_before_tick_0(procs, ros_env, tmp_path):
    """Only r1 and r3 run: after world.start_timeout_s the run fails naming r2's topic."""
    _robots(procs, "e5.5", ["r1,r3"], tmp_path / "twists.jsonl")
    out = tmp_path / "run"
    run = _run(procs, "e5.5", out, "--set", "world.start_timeout_s=5")
    _, err = run.communicate(timeout=200)
    assert run.returncode == 1
    assert "no pose within 5 s from r2 (/r2/odom)" in err.decode()


LISTENER = r"""
import json, signal, sys, threading
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from nav_msgs.msg import Odometry, Path
from rclpy.signals import SignalHandlerOptions
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
node = rclpy.create_node("copath_test_listener")
seen = {}
last = {}
stamps = {}
def cb(topic):
    def f(msg):
        seen[topic] = seen.get(topic, 0) + 1
        if isinstance(msg, Odometry):
            last[topic] = [msg.pose.pose.position.x, msg.pose.pose.position.y, msg.header.frame_id, msg.child_frame_id]
            stamps.setdefault(topic, []).append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
        else:
            last[topic] = len(msg.poses)
    return f
latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
for topic in sys.argv[1].split(","):
    typ = Odometry if topic.endswith("/odom") else Path
    node.create_subscription(typ, topic, cb(topic), latched if typ is Path else 10)
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *a: stop.set())
print("ready", flush=True)
while not stop.is_set():
    rclpy.spin_once(node, timeout_sec=0.1)
print(json.dumps({"seen": seen, "last": last, "stamps": stamps}), flush=True)
"""


DURATION = 20.0
"""Simulated length [s] of the mirrored run (400 ticks, 8-10 s of wall time)."""
MIN_TICKS = 20
"""Ticks the subscriber must see of each robot's odometry, once matched (1 s of the run)."""


def test_simulated_run_is_mirrored_into_ros2_live(procs, ros_env, tmp_path):
    """copath run --ros2: a ROS 2 subscriber sees every robot's odometry (frame map), the
    DMPC's broadcast horizon as nav_msgs/Path and the reference path.

    Every tick from the first one the subscriber gets to the last: DDS matches the
    subscriber with the mirror's publishers while the fleet starts, which on a loaded
    machine took past the run's first second (25-40 of its 80 ticks, old and new code
    alike), so the count of a fast lockstep run is not the test; the gaps are, and the last
    tick (the last odometry is the last truth). In `.ci/run`'s fleet tier (2026-12-03) the
    match took longer than a whole 4 s run (80 ticks, about 3 s of wall time): the subscriber
    got nothing, and on the idle machine, with a 10 s run, it saw 22 of 200 ticks in one of six
    tries, nothing in two: the match took about 5 s. The run lasts 20 s now (400 ticks, 8-10 s
    of wall time), and the subscriber must see at least MIN_TICKS of them."""
    topics = ["/r1/odom", "/r2/odom", "/r3/odom", "/r1/plan", "/paths/main"]
    listener = procs.start(["-c", LISTENER, ",".join(topics)])
    assert listener.stdout.readline().strip() == b"ready"
    out = tmp_path / "run"
    run = procs.start(["-m", "orchestrator", "run", "e5.2-dmpc-ellipse-triangle", "--ros2", "--duration", str(DURATION),
                       "--set", "run.settle_s=1", "--out", str(out), "-q", "--no-plots"])
    _, err = run.communicate(timeout=300)
    assert run.returncode in (0, 3), err.decode()[-2000:]
    time.sleep(0.5)
    listener.send_signal(signal.SIGTERM)
    got = json.loads(listener.communicate(timeout=30)[0].decode().strip().splitlines()[-1])
    ticks = round(DURATION / 0.05)  # E5.2: dt = 0.05 s
    for n in ("r1", "r2", "r3"):
        assert f"/{n}/odom" in got["stamps"], got
        st = got["stamps"][f"/{n}/odom"]  # header stamps: the run's start + t, one per tick
        k = sorted(round((s - st[0]) / 0.05) for s in st)
        assert MIN_TICKS <= len(k) <= ticks and len(set(k)) == len(k), got["seen"]  # each tick once
        # once matched, hardly any lost: the view's QoS keeps the last 10 per topic, and a
        # subscriber starved of CPU (two busy loops beside the fleet) lost 6 of 56
        span = k[-1] - k[0] + 1
        assert span - len(k) <= max(3, span // 8), (n, k)
        assert got["last"][f"/{n}/odom"][2:] == ["map", f"{n}/base_link"]
    assert got["seen"]["/r1/plan"] >= 1 and got["last"]["/r1/plan"] > 1
    assert got["seen"]["/paths/main"] == 1 and got["last"]["/paths/main"] >= 50
    poses = read_log(out / "run.mcap")
    last_truth = [r for _, _, r in poses.records if getattr(r, "TYPE", "") == "truth"][-1]
    assert got["last"]["/r1/odom"][:2] == pytest.approx(last_truth.poses[0][:2])


def test_agent_with_ros2_io_drives_its_robot_without_the_bridge(procs, ros_env, tmp_path):
    """world.robots.r2.commands = "agent": r2's agent (copath agent --io ros2) reads /r2/odom
    and publishes /r2/cmd_vel itself; the column still forms (E5.5)."""
    record = tmp_path / "twists.jsonl"
    _robots(procs, "e5.5", None, record)
    out = tmp_path / "run"
    run = _run(procs, "e5.5", out, "--set", "world.robots.r2.commands=agent", "--duration", "30",
               "--set", "run.settle_s=20")
    _, err = run.communicate(timeout=400)
    assert run.returncode in (0, 3), err.decode()[-2000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["fleet"]["coordination_error_max_m"] < 0.05 and m["fleet"]["collisions"] == 0, m["fleet"]
    assert m["robots"]["r2"]["path_error_max_m"] < 0.05
    r2 = _stats(out / "run.mcap", "r2")
    assert r2["ros2_poses"] > 300 and r2["ros2_twists"] > 300  # its own odometry in, its own Twists out
    assert "ros2_poses" not in _stats(out / "run.mcap", "r1")  # r1 is driven through the bridge
    assert any(any(t["cmd"]) for t in _twists(record) if t["robot"] == "r2")
