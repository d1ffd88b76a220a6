"""A robot reported lost (Observation.lost, from liveliness) leaves its neighbours' graphs
at once: the kit forgets its messages, DMPC drops its coupling term."""

from __future__ import annotations

import numpy as np

from agent.controllers.dmpc import build
from copath.control import LatestMessages, Observation, PeerMessage
from tests.unit.test_dmpc import DT, PATH, _ctx


def _coord(sender, stamp):
    return PeerMessage(sender, "coord_state", stamp, 0.0, {"s": 1.0, "sdot": 0.2, "s_d": 0.0})


def test_latest_messages_forgets_a_lost_sender():
    inbox = LatestMessages(kinds=("coord_state",))
    inbox.update([_coord("r2", 0.1), _coord("r3", 0.1)], 0.1)
    assert set(inbox.of_kind("coord_state")) == {"r2", "r3"}
    inbox.update([_coord("r2", 0.2)], 0.2, lost=frozenset({"r3"}))
    assert set(inbox.of_kind("coord_state")) == {"r2"}
    inbox.update([_coord("r3", 0.3)], 0.3)  # back (rejoined): heard again
    assert set(inbox.of_kind("coord_state")) == {"r2", "r3"}


def test_dmpc_drops_the_coupling_of_a_lost_neighbour():
    ctrl = build(_ctx())
    pose = np.array([*PATH.pos(0.0), PATH.theta(0.0)])
    nb = PeerMessage("r2", "assumed_traj", 0.0, DT, {"t0": 0.0, "dt": DT, "s_hat": [0.6, 0.62, 0.64], "psi_scale": 1.0})
    res = ctrl.step(Observation(t=DT, pose=pose, dt=DT), [nb])
    assert res.telemetry["neighbours_used"] == 1
    res = ctrl.step(Observation(t=2 * DT, pose=pose, dt=DT, lost=frozenset({"r2"})), [])
    assert res.telemetry["neighbours_used"] == 0 and "r2" not in ctrl.neighbour_traj
