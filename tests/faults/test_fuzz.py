"""Fuzz a running fleet: thousands of random byte strings, truncated and oversized msgpack,
wrong wire versions and well-formed forgeries on the run's keys. Open bus: nothing
crashes and every message r1 was sent is counted as a reject. Secure mode with a
compromised robot's credentials: nothing reaches anyone and the run meets its targets."""

from __future__ import annotations

import json
import random
import time

import pytest

from copath.wire.keys import Keys
from copath.wire.messages import Command, Start
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint
from orchestrator.testkit.fuzz import fuzz_payloads
from orchestrator.testkit.scenarios import config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(300)]


def _run(tmp_path, procs, extra):
    port = free_port()
    p = procs.start(["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path), "--run-id", "fuzz",
                     "--duration", "200", "--listen", loopback_endpoint(port), "-q", "--no-plots", *extra])
    return p, loopback_endpoint(port)


def _wait_until_running(p, mcap, deadline):
    while not (mcap.is_file() and mcap.stat().st_size > 300_000):
        assert p.poll() is None and time.monotonic() < deadline, p.stderr.read().decode()[-2000:]
        time.sleep(0.05)


def test_fuzzing_an_open_fleet_crashes_nothing_and_every_reject_is_counted(tmp_path, procs):
    p, ep = _run(tmp_path, procs, ["--no-secure"])
    keys = Keys("fuzz")
    rng = random.Random(10)
    sent = 0
    with ZenohLink.open(SessionConfig(mode="client", connect=(ep,), extra=(("connect/timeout_ms", "60000"),))) as bad:
        _wait_until_running(p, tmp_path / "run.mcap", time.monotonic() + 150)
        # r1 listens to its observation key, r2's broadcasts and direct messages, sim/start and sim/end
        targets = [keys.obs("r1"), keys.peer_broadcast("r2"), keys.peer_direct("r2", "r1"), keys.start, keys.end]
        for i, data in enumerate(fuzz_payloads(rng, 3000, "r1", "r2")):
            bad.publish_bytes(targets[i % len(targets)], data)
            sent += 1
            if i % 200 == 0:
                time.sleep(0.01)
        # and the simulator's command keys
        for data in fuzz_payloads(rng, 300, "sim", "r2"):
            bad.publish_bytes(keys.cmd("r1"), data)
        time.sleep(0.5)
    assert p.wait(timeout=240) == 0, p.stderr.read().decode()[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"]
    # every message r1 was sent is counted (a copy the safety filter's overhearing
    # subscription also received may be counted twice, depending on how the node subscribes)
    peer = sum(1 for i in range(sent) if i % 5 in (1, 2))
    assert sent <= m["robots"]["r1"]["messages_rejected"] <= sent + peer
    # r3 hears sim/start and sim/end and r2's broadcasts (r2 is its neighbour)
    bcast = sum(1 for i in range(sent) if i % 5 == 1)
    sim_keys = sum(1 for i in range(sent) if i % 5 in (3, 4))
    assert m["robots"]["r3"]["messages_rejected"] >= bcast + sim_keys
    assert m["fleet"]["messages_rejected"] >= sent + 300


def test_fuzzing_a_secure_fleet_with_a_robots_credentials_reaches_nobody(tmp_path, procs):
    p, ep = _run(tmp_path, procs, ["--secure"])
    keys = Keys("fuzz")
    rng = random.Random(11)
    cred = tmp_path / "secrets" / "r2.json5"
    deadline = time.monotonic() + 150
    while not cred.is_file():
        assert p.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    conf = SessionConfig(mode="client", connect=(ep,), config_file=str(cred), extra=(("connect/timeout_ms", "60000"),))
    with ZenohLink.open(conf) as bad:
        _wait_until_running(p, tmp_path / "run.mcap", deadline)
        targets = [keys.obs("r1"), keys.peer_broadcast("r1"), keys.peer_direct("r3", "r1"), keys.start, keys.end,
                   keys.cmd("r1"), keys.truth]
        payloads = fuzz_payloads(rng, 3000, "r1", "r3")
        payloads += [Command(5, 0.5, [2.0, 2.0], 0.0, {}).pack(), Start(0.0, 0.1, "lockstep").pack()]
        for i, data in enumerate(payloads):
            bad.publish_bytes(targets[i % len(targets)], data)
            if i % 200 == 0:
                time.sleep(0.01)
        time.sleep(0.5)
    assert p.wait(timeout=240) == 0, p.stderr.read().decode()[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"] and m["fleet"]["coordination_error_max_m"] < 0.02
    assert m["fleet"]["messages_rejected"] == 0  # the router let none of it through
