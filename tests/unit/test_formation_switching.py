"""E6.6 formation switching: slot schedule, quintic offsets (5.1)-(5.3) and config checks."""

import math

import numpy as np
import pytest

from copath.control import Observation, RobotContext
from agent.controllers.formation_switching import FormationSwitchingConfig, build
from copath.config import ConfigError, from_table
from copath.models import UnicycleModel
from copath.paths import line

SLOTS = [[0.0, 0.5], [0.6, 0.0], [0.4, 0.0]]


def _ctx(params):
    return RobotContext(name="r1", index=0, model=UnicycleModel(v_max=0.5, omega_max=1.0),
                        paths={"main": line((0.0, 0.0), 0.0, 30.0)}, path="main", neighbours=(),
                        robots=("r1",), dt=0.1, params=params)


def test_slots_switch_smoothly_at_the_scheduled_formation_coordinate():
    ctl = build(_ctx({"slots": SLOTS, "switch_at": [3.0, 7.5], "transition_m": 2.0}))
    s_grid = np.arange(0.0, 14.0, 0.01)
    sd, q, moving, form = [], [], [], []
    for s in s_grid:
        ctl._schedule(s)
        v = ctl._slot(s)
        sd.append(v[0])
        q.append(v[2])
        moving.append(v[5])
        form.append(ctl.formation)
    sd, q = np.array(sd), np.array(q)
    # the switch to the column begins when xi = s - s_d reaches 3.0 (s = 3.0 with s_d = 0)
    first = s_grid[np.argmax(np.array(form) == 1)]
    assert first == pytest.approx(3.0, abs=0.011)
    # offsets change continuously (quintic, no jumps) and end at the new slots
    assert np.max(np.abs(np.diff(q))) < 0.01 and np.max(np.abs(np.diff(sd))) < 0.01
    assert q[s_grid < 3.0].max() == pytest.approx(0.5) and sd[s_grid < 3.0].max() == pytest.approx(0.0)
    col = (s_grid > 5.01) & (s_grid < 8.0)
    np.testing.assert_allclose(q[col], 0.0, atol=1e-12)
    np.testing.assert_allclose(sd[col], 0.6, atol=1e-12)
    # the second switch begins at xi = 7.5, i.e. s = 8.1 with s_d = 0.6
    second = s_grid[np.argmax(np.array(form) == 2)]
    assert second == pytest.approx(8.1, abs=0.011)
    np.testing.assert_allclose(sd[s_grid > 10.2], 0.4, atol=1e-12)
    assert not any(m for m, s in zip(moving, s_grid) if s < 3.0 or 5.01 < s < 8.1)


def test_robot_on_its_slot_drives_along_the_offset_path():
    ctl = build(_ctx({"slots": [[0.0, 0.5]], "switch_at": [], "v0": 0.2, "s0": 1.0}))
    pose = np.array([1.0, 0.5, 0.0])
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    for k in range(200):
        res = ctl.step(Observation(t=0.1 * k, pose=pose, dt=0.1), [])
        pose = model.step(pose, res.command, 0.1)
    assert abs(pose[1] - 0.5) < 0.01 and abs(math.sin(pose[2])) < 0.01
    assert res.telemetry["formation_error"] < 0.02
    assert res.telemetry["speed_error"] == pytest.approx(0.0, abs=1e-3)


def test_config_checks():
    with pytest.raises(ConfigError, match="switch_at"):
        from_table(FormationSwitchingConfig, {"slots": SLOTS, "switch_at": [3.0]}, "controller")
    with pytest.raises(ConfigError, match="switch_at"):
        from_table(FormationSwitchingConfig, {"slots": SLOTS, "switch_at": [5.0, 3.0]}, "controller")
    with pytest.raises(ConfigError, match="slots"):
        from_table(FormationSwitchingConfig, {}, "controller")
