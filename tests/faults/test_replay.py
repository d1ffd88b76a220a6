"""copath replay waits for its audience, paces by simulated time and records what it
republishes; a fresh recorder hears every message of the log, in order."""

from __future__ import annotations

import time

import pytest

from copath.wire.keys import Keys
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint
from orchestrator.log.mcap import iter_raw
from orchestrator.log.writer import Recorder
from orchestrator.log.replay import parse_wait_for

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(240)]


@pytest.fixture
def lockstep_log(e55_log):
    return e55_log


def test_wait_for_is_sessions_or_seconds():
    assert parse_wait_for("2") == (2, 0.0) and parse_wait_for("1.5s") == (0, 1.5) and parse_wait_for(None) == (0, 0.0)
    with pytest.raises(ValueError, match="--wait-for = 'soon' is not allowed"):
        parse_wait_for("soon")


def test_a_replay_into_a_fresh_recorder_delivers_every_message_in_order(tmp_path, procs, lockstep_log):
    ep = loopback_endpoint(free_port())
    p = procs.start(["-m", "orchestrator", "replay", str(lockstep_log), "--listen", ep, "--run-id", "again",
                     "--wait-for", "1", "--speed", "20", "--record", str(tmp_path / "recorded.mcap")])
    time.sleep(1.0)  # the replay is up and waiting: a late subscriber must still hear all of it
    keys = Keys("again")
    rec = Recorder(tmp_path / "heard.mcap", keys, {"copath": {"run_id": "again"}, "scenario": {"json": "{}"}})
    with ZenohLink.open(SessionConfig(mode="client", connect=(ep,), extra=(("connect/timeout_ms", "30000"),))) as sub:
        sub.subscribe_raw(keys.all, rec.write)
        assert p.wait(timeout=180) == 0, p.stderr.read().decode()[-2000:]
        time.sleep(0.3)
    rec.finish()
    src = [("copath/again/" + k.split("/", 2)[2], d) for _, k, d in iter_raw(lockstep_log)]
    heard = [(k, d) for _, k, d in iter_raw(tmp_path / "heard.mcap")]
    recorded = [(k, d) for _, k, d in iter_raw(tmp_path / "recorded.mcap")]
    assert len(src) > 3000
    assert heard == src  # every message, in order
    assert recorded == src


def test_pacing_by_simulated_time_replays_a_lockstep_log_in_real_time(tmp_path, lockstep_log):
    from orchestrator.log.replay import replay

    t0 = time.monotonic()
    res = replay(lockstep_log, speed=16.0, pace="sim", start_delay_s=0.0)
    wall = time.monotonic() - t0
    assert res.published > 3000
    assert 31.9 / 16 - 0.1 <= res.duration_s <= 32.0 / 16 + 0.1  # due times follow the simulated clock
    assert wall >= res.duration_s
