"""The idle controller of ``copath bench floor`` (orchestrator/studies/bench/idle.py): a constant
command, one message per step only when asked, nothing read from what it hears; it builds
from E5.4 with only ``controller.type`` changed, and bad arguments of the floor are refused
naming them."""

from __future__ import annotations

import numpy as np
import pytest

from copath.control import Observation, PeerMessage, RobotContext
from orchestrator import api
from orchestrator.cli import main as copath
from orchestrator.studies.bench.idle import build


def _law(message: bool):
    sc = api.load("e5.4", ['controller={type = "orchestrator.studies.bench.idle:build", message = %s, v = 0.1}'
                           % str(message).lower()])
    return sc, sc.robots[1].name


@pytest.mark.parametrize("message", [False, True])
def test_idle_commands_a_constant_and_sends_at_most_one_message(message):
    sc, name = _law(message)
    law = build(RobotContext.for_robot(sc, name))  # the factory, with the robot's merged parameters
    heard = [PeerMessage("r1", "idle_state", 0.0, 0.0, {"s": 1.0, "sdot": 0.0, "s_d": 0.0})]
    for k in range(3):
        res = law.step(Observation(t=0.1 * k, pose=np.array([0.3 * k, -1.0, 2.0]), dt=0.1), heard if k else [])
        np.testing.assert_array_equal(res.command, [0.1, 0.0])
        assert len(res.messages) == (1 if message else 0)
    if message:
        (m,) = res.messages
        assert m.kind == "idle_state" and m.payload == {"s": pytest.approx(0.2), "sdot": 0.1, "s_d": -0.5}


@pytest.mark.parametrize("arg, value, words", [("--robots", "0", ">= 1"), ("--ticks", "-3", ">= 1"),
                                               ("--puts", "two", "whole number"), ("--warmup", "-1", ">= 0")])
def test_floor_refuses_a_bad_count_naming_it(arg, value, words, capsys):
    with pytest.raises(SystemExit) as e:
        copath(["bench", "floor", arg, value, "--no-irsim"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and f"{arg} = {value!r} is not allowed" in err and words in err, err
