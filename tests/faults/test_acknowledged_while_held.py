"""E5.4's ``safety.acknowledge_plans = "while_held"`` over Zenoh, under both clocks
(docs/reference/safety.md, "Acknowledged plans while a robot is held"): a robot process killed
mid-run, the live robots leave out the plans no robot holds any more from its loss on, and
only then; they go round it and touch nothing."""

from __future__ import annotations

import pytest

from orchestrator.testkit.processes import killed_mid_run
from orchestrator.testkit.records import closing_counters
from tests.conftest import config

pytestmark = [pytest.mark.faults, pytest.mark.fleet, pytest.mark.timeout(400)]


@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_after_a_kill_the_live_robots_leave_out_unacknowledged_plans_over_zenoh(tmp_path, procs, clock):
    duration = 30.0
    p = procs.start(["-m", "orchestrator", "run", str(config("e5.4-six-robots-lemniscate")), "--out", str(tmp_path),
                     "--run-id", "ackh", "--duration", f"{duration:g}", "-q", "--no-plots",
                     "--set", 'run.on_robot_failure="continue"', "--set", f'run.clock="{clock}"',
                     "--set", "run.settle_s=10"])
    # about 11 s of the run, in its own time
    m, records, lost = killed_mid_run(p, tmp_path, "r4", under_way_bytes=300_000)
    assert len(lost) == 1 and 3.0 < lost[0] < duration - 5.0, lost  # mid-run
    assert m["ok"] and m["fleet"]["collisions"] == 0
    assert m["fleet"]["messages_published"] == m["fleet"]["messages_recorded"]
    steps = closing_counters(records, "safety_ack_steps")  # a killed process leaves none
    assert set(steps) == {"r1", "r2", "r3", "r5", "r6"}
    after = (duration - lost[0]) / 0.1 + 3  # steps after the loss (a realtime step may come early)
    assert all(0 < k <= after for k in steps.values()), (steps, lost)
    assert m["robots"]["r5"]["detours"] >= 1  # right behind r4 on the column: it went round
