"""Forged and malformed records published onto a running fleet's keys (no secure mode):
nothing crashes, no queue blocks, a forged end does not end the run, every reject is
counted in metrics.json and appears as an event in the log."""

from __future__ import annotations

import json
import math
import time

import msgpack
import pytest

from copath.wire.keys import Keys
from copath.wire.messages import End, PeerEnvelope
from copath.wire.session import free_port, loopback_endpoint
from orchestrator.log.mcap import read_log
from orchestrator.testkit.attacker import attacker, wait_for_truth
from orchestrator.testkit.scenarios import config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(240)]


def test_forgeries_and_garbage_are_rejected_counted_and_survived(tmp_path, procs):
    port = free_port()
    run_id = "forge"
    keys = Keys(run_id)
    p = procs.start(["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path), "--run-id", run_id,
                     "--duration", "40", "--listen", loopback_endpoint(port), "-q", "--no-plots",
                     "--no-secure"])  # an open bus: what the receivers do on their own
    with attacker(loopback_endpoint(port)) as bad:
        wait_for_truth(bad, keys, 20, p)
        nan_peer = PeerEnvelope("r2", 1, 0.5, "coord_state", [0.0, 0.0], {"s": 0.0, "sdot": 0.2, "s_d": 0.0}).to_dict()
        nan_peer["payload"]["s"] = math.nan
        nan_stamp = dict(nan_peer, stamp=math.nan, payload={"s": 0.0, "sdot": 0.2, "s_d": 0.0})
        forged = {
            keys.end: [End(5, 0.5, "forged end", True).pack()],                  # looks like the simulator's
            keys.peer_broadcast("r2"): [
                msgpack.packb(nan_peer), msgpack.packb(nan_stamp),               # NaN payload, NaN stamp
                PeerEnvelope("r3", 1, 0.5, "coord_state", [0.0, 0.0],            # sender does not match key
                             {"s": 0.0, "sdot": 0.2, "s_d": 0.0}).pack(),
                PeerEnvelope("r2", 10**6, 1e9, "coord_state", [0.0, 0.0],        # stamp from the far future
                             {"s": 0.0, "sdot": 0.2, "s_d": 0.0}).pack(),
                b"\x00garbage", msgpack.packb({"v": 99, "type": "peer"}),
            ],
            keys.obs("r1"): [End(5, 0.5, "on the wrong key", True).pack()],
        }
        for key, payloads in forged.items():
            for data in payloads:
                bad.publish_bytes(key, data)
        time.sleep(0.5)
    assert p.wait(timeout=200) == 0, p.stderr.read().decode()[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"] and m["failure"] is None
    assert m["fleet"]["coordination_error_max_m"] < 0.05
    # r1 and r3 listen to r2 (fixed graph of E5.5): each refused the six peer forgeries
    for name in ("r1", "r3"):
        if "r2" in _neighbours(tmp_path, name):
            assert m["robots"][name]["messages_rejected"] >= 6, (name, m["robots"][name])
    assert m["robots"]["r1"]["messages_rejected"] >= 2  # plus the wrong-key record and the forged end
    assert m["fleet"]["messages_rejected"] >= sum(r["messages_rejected"] for r in m["robots"].values())
    log = read_log(tmp_path / "run.mcap")
    events = [r for _, k, r in log.records if getattr(r, "TYPE", "") == "event" and r.what == "messages_rejected"]
    assert {e.source for e in events} >= {"r1"}
    assert sum(e.detail["count"] for e in events if e.source == "r1") == m["robots"]["r1"]["messages_rejected"]


def _neighbours(run_dir, name: str) -> list[str]:
    raw = json.loads((run_dir / "scenario.json").read_text())
    for r in raw["robots"]:
        if r["name"] == name:
            return list(r.get("neighbours") or [])
    return []
