"""A restarted robot's coordination state (docs/reference/faults.md, "Restart"): the Sec. 5.5
consensus virtual vehicle of a process that joined a run in progress starts from its
neighbours' progress, not from its own projection; a robot at the run's start keeps its
projection."""

import numpy as np
import pytest

from agent.controllers.consensus import build
from copath.control import Observation, PeerMessage, RobotContext
from copath.models import UnicycleModel
from copath.paths import lemniscate

PATH = lemniscate(2.0)
DT = 0.1


def _robot(s_d: float = -0.5):
    ctx = RobotContext(name="r2", index=1, model=UnicycleModel(), paths={"main": PATH}, path="main",
                       neighbours=("r1", "r3"), robots=("r1", "r2", "r3"), dt=DT,
                       params={"s_d": s_d, "v0": 0.2})
    return build(ctx)


def _state(sender: str, s: float, s_d: float, t: float, age: float = 0.0) -> PeerMessage:
    return PeerMessage(sender, "coord_state", t - age, age, {"s": s, "sdot": 0.2, "s_d": s_d, "sddot": 0.0})


def _pose(s: float) -> np.ndarray:
    x, y = np.asarray(PATH.pos(s), float).reshape(-1)[:2]
    return np.array([x, y, float(PATH.frame(s)[2])])


@pytest.mark.parametrize("joined", [False, True])
def test_a_restarted_robot_starts_its_virtual_vehicle_from_its_neighbours(joined):
    t = 40.0
    ctl = _robot()
    # r1 at s = 3.0 (xi 3.0), r3 at s = 2.0 (xi 3.0): the team's xi is 3.0; r2 stands at
    # s = 2.2 (xi 2.7), 0.3 m behind its slot after its outage
    inbox = [_state("r1", 3.0, 0.0, t), _state("r3", 2.0, -1.0, t)]
    res = ctl.step(Observation(t=t, pose=_pose(2.2), dt=DT, joined=joined), inbox)
    if joined:
        assert res.telemetry["xi"] == pytest.approx(3.0, abs=1e-9)  # s = 2.5: its slot, not its position
        assert res.telemetry["sdot"] == pytest.approx(0.2)
        assert res.command[0] > 0.2  # it drives to catch up with its virtual vehicle
    else:
        assert res.telemetry["xi"] == pytest.approx(2.7, abs=1e-6)  # its projection (Sec. 5.5 as written)


def test_without_neighbour_messages_a_restarted_robot_keeps_its_projection():
    ctl = _robot()
    res = ctl.step(Observation(t=40.0, pose=_pose(2.2), dt=DT, joined=True), [])
    assert res.telemetry["xi"] == pytest.approx(2.7, abs=1e-6)


def test_a_restarted_robot_that_hears_its_neighbours_one_step_late_moves_to_them_then():
    """In one process a new node hears only what is sent after it started: its first step has
    no neighbour message, its second does."""
    t = 40.0
    ctl = _robot()
    first = ctl.step(Observation(t=t, pose=_pose(2.2), dt=DT, joined=True), [])
    assert first.telemetry["xi"] == pytest.approx(2.7, abs=1e-6)
    inbox = [_state("r1", 3.0 + 0.2 * DT, 0.0, t + DT), _state("r3", 2.0 + 0.2 * DT, -1.0, t + DT)]
    second = ctl.step(Observation(t=t + DT, pose=_pose(2.2), dt=DT, joined=True), inbox)
    assert second.telemetry["xi"] == pytest.approx(3.0 + 0.2 * DT, abs=1e-9)
    later = ctl.step(Observation(t=t + 2 * DT, pose=_pose(2.2), dt=DT, joined=True),
                     [_state("r1", 5.0, 0.0, t + 2 * DT)])  # once moved, the law (5.42) alone drives it
    assert 0.0 < later.telemetry["xi"] - second.telemetry["xi"] < 0.5 * DT  # integrated, not moved to r1's 5.0
