"""The ROS 2 bridge's rules in one process (sim/ros2_bridge.py; no ROS 2 needed): first
poses, frames, saturation, holding, zero on exit, the pose lease."""

from __future__ import annotations

import math

import pytest

from copath.wire.keys import Keys
from copath.wire.link import MemoryBus
from copath.wire.messages import Command, Event, Obs
from orchestrator import api
from sim.ros2_bridge import BridgeNode


@pytest.fixture
def bridge(monkeypatch):
    # the bridge's rules need no ROS 2: validation's "is ROS 2 installed" check is waived here
    monkeypatch.setattr("copath.ros2.missing", lambda *a, **k: None)
    scenario = api.load("e5.5", {"world.backend": "ros2", "run.clock": "realtime",
                                 "world.robots.r3.frame": "map", "world.robots.r3.origin": [1.0, 0.0, math.pi / 2]})
    sent = []
    bus = MemoryBus()
    link = bus.link()
    seen = []
    bus.link().subscribe("copath/t/**", lambda k, r: seen.append((k, r)))
    node = BridgeNode(scenario, Keys("t"), link, lambda n, c: sent.append((n, [float(v) for v in c])))
    node.start()
    return node, sent, seen


def test_first_poses_are_mapped_by_origin_and_checked_for_frame(bridge):
    node, _, _ = bridge
    node.on_pose("r1", (0.0, 0.0, 0.0), 1.0, "r1/odom")
    node.on_pose("r2", (0.1, 0.0, 0.0), 1.0, "r2/odom")
    node.on_pose("r3", (1.0, 0.0, 0.0), 1.0, "odom")  # not the frame r3 must report in
    assert node.counts["frame_rejects"]["r3"] == 1 and "r3" not in node.pose
    node.on_pose("r3", (1.0, 0.0, 0.0), 1.0, "map")
    start = node.scenario.robot("r1").pose
    assert node.pose["r1"][:2] == pytest.approx(start[:2])  # origin "start"
    assert math.sin(node.pose["r1"][2] - start[2]) == pytest.approx(0.0, abs=1e-12)
    assert node.pose["r3"][:2] == pytest.approx((1.0, 1.0))  # origin [1, 0, pi/2]
    assert node._wait_first_poses() is None


def test_silent_topics_are_named(bridge):
    node, _, _ = bridge
    node.scenario = node.scenario.with_overrides(world={"start_timeout_s": 0.05})
    node.on_pose("r1", (0.0, 0.0, 0.0), 1.0, "r1/odom")
    why = node._wait_first_poses()
    assert why.startswith("no pose within 0.05 s from r2 (/r2/odom), r3 (/r3/odom)")


def test_commands_are_saturated_counted_and_zeroed_on_exit(bridge):
    node, sent, _ = bridge
    node._started_run = True
    node._on_cmd("copath/t/robot/r1/cmd", Command(0, 0.0, [2.0, 0.0]))  # v_max = 0.5
    node._on_cmd("copath/t/robot/r2/cmd", Command(0, 0.0, [0.1, 0.2]))
    assert node.counts["saturated"] == {"r1": 1, "r2": 0, "r3": 0}
    assert node.requested["r1"] == pytest.approx([0.5, 0.0]) and node.violated["r1"]
    assert all(abs(c[0]) <= 0.5 for n, c in sent if n == "r1")  # a_max ramps, never above the limit
    node._hold("r2", "test")
    assert sent[-1] == ("r2", [0.0, 0.0])
    node._on_cmd("copath/t/robot/r2/cmd", Command(1, 0.1, [0.1, 0.2]))
    assert node.counts["held_commands"]["r2"] == 1 and sent[-1] == ("r2", [0.0, 0.0])
    del sent[:]
    node.stop_robots()
    assert sorted(sent) == [("r1", [0.0, 0.0]), ("r2", [0.0, 0.0]), ("r3", [0.0, 0.0])]
    node._on_cmd("copath/t/robot/r1/cmd", Command(2, 0.2, [0.3, 0.0]))  # nothing moves a robot after the end
    assert all(c == [0.0, 0.0] for _, c in sent)


def test_pose_lease_loses_the_robot_under_each_policy(bridge):
    node, sent, seen = bridge
    for n in node.names:
        node.on_pose(n, (0.0, 0.0, 0.0), 1.0, "map" if n == "r3" else f"{n}/odom")
    node._started_run = True
    now = node.pose_at["r2"] + node.scenario.run.lease_s + 0.1
    node.pose_at["r1"] = node.pose_at["r3"] = now
    assert node._pose_watch(now).startswith("robot r2 lost: no pose on /r2/odom for 1.10 s")
    assert sent[-1] == ("r2", [0.0, 0.0]) and "r2" in node.held
    node.policy = "continue"
    node.pose_lost.clear()
    node.held.clear()
    assert node._pose_watch(now) is None
    assert [(r.what, r.detail["robot"]) for _, r in seen if isinstance(r, Event)] == [("robot_lost", "r2")]
    node.on_pose("r2", (0.0, 0.0, 0.0), 1.0, "r2/odom")
    assert node._pose_watch(node.pose_at["r2"]) is None and "r2" not in node.held
    assert [r.what for _, r in seen if isinstance(r, Event)][-1] == "robot_rejoined"


def test_observations_go_out_only_during_the_run(bridge):
    node, _, seen = bridge
    node.on_pose("r1", (0.0, 0.0, 0.0), 1.0, "r1/odom")
    assert not [r for _, r in seen if isinstance(r, Obs)]  # before tick 0: nothing
    node._t0 = 0.0
    node.on_pose("r1", (0.0, 0.0, 0.0), 1.0, "r1/odom")
    assert [k for k, r in seen if isinstance(r, Obs)] == ["copath/t/robot/r1/obs"]
    node.stop_robots()
    node.on_pose("r1", (0.0, 0.0, 0.0), 1.0, "r1/odom")
    assert len([r for _, r in seen if isinstance(r, Obs)]) == 1  # none after the end


def test_an_agent_that_goes_quiet_has_its_robot_stopped(bridge):
    node, sent, _ = bridge
    for n in node.names:
        node.on_pose(n, (0.0, 0.0, 0.0), 1.0, "map" if n == "r3" else f"{n}/odom")
    node.duration_s = 0.2 + node.stale_s
    node._started_run = True
    node._on_cmd("copath/t/robot/r1/cmd", Command(0, 0.0, [0.3, 0.0]))
    k, ok, _ = node._realtime()  # r1's agent says nothing more for the rest of the run
    assert ok and node.counts["stale_stops"]["r1"] == 1
    assert list(node.requested["r1"]) == [0.0, 0.0]  # towards zero, as fast as its a_max allows
    v = [c[0] for n, c in sent if n == "r1"]
    assert v[-1] < max(v) and all(b <= a + 1e-12 for a, b in zip(v[v.index(max(v)):], v[v.index(max(v)) + 1:]))
