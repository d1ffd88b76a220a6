"""A fleet across two Linux network namespaces ("hosts"), one Zenoh router per host,
connected by a veth pair whose link is throttled: the run completes and the MCAP holds
every robot. Needs root and ``ip netns``; skipped with the reason otherwise.

The impairment is a token-bucket rate limit (``tc tbf``) on host A's side of the link:
this machine's kernel has no netem and no iptables/nftables binary, so random drop is not
available (docs/faults.md)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
import uuid

import pytest

from orchestrator.mcaplog import read_log
from tests.conftest import REPO, config

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]


def _ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20)


def _why_not() -> str | None:
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    probe = f"cpprobe{os.getpid()}"
    res = _ip("netns", "add", probe)
    if res.returncode != 0:
        return f"ip netns add is not permitted here: {res.stderr.strip()}"
    _ip("netns", "del", probe)
    return None


@pytest.fixture
def two_hosts():
    why = _why_not()
    if why:
        pytest.skip(why)
    tag = uuid.uuid4().hex[:6]
    a, b = f"cpA{tag}", f"cpB{tag}"
    va, vb = f"va{tag}", f"vb{tag}"
    try:
        for cmd in (["netns", "add", a], ["netns", "add", b], ["link", "add", va, "type", "veth", "peer", "name", vb],
                    ["link", "set", va, "netns", a], ["link", "set", vb, "netns", b],
                    ["-n", a, "addr", "add", "10.77.0.1/24", "dev", va], ["-n", b, "addr", "add", "10.77.0.2/24", "dev", vb],
                    ["-n", a, "link", "set", va, "up"], ["-n", b, "link", "set", vb, "up"],
                    ["-n", a, "link", "set", "lo", "up"], ["-n", b, "link", "set", "lo", "up"]):
            res = _ip(*cmd)
            if res.returncode != 0:
                pytest.skip(f"ip {' '.join(cmd)} failed: {res.stderr.strip()}")
        tbf = subprocess.run(["ip", "netns", "exec", a, "tc", "qdisc", "add", "dev", va, "root", "tbf", "rate", "4mbit",
                              "burst", "32kbit", "latency", "50ms"], capture_output=True, text=True, timeout=20)
        if tbf.returncode != 0:
            pytest.skip(f"tc tbf on the link failed: {tbf.stderr.strip()}")
        yield a, b
    finally:
        _ip("netns", "del", a)
        _ip("netns", "del", b)


_ROUTER = """
import signal, sys, time
from copath.wire.session import SessionConfig, ZenohLink
link = ZenohLink.open(SessionConfig(mode="router", listen=(sys.argv[1],), connect=(sys.argv[2],)))
print("router up", flush=True)
signal.signal(signal.SIGTERM, lambda *a: sys.exit(0))
try:
    while True:
        time.sleep(0.2)
finally:
    link.close()
"""


def test_a_fleet_across_two_hosts_with_a_throttled_link(tmp_path, procs, two_hosts):
    a, b = two_hosts
    env = {"PYTHONPATH": str(REPO)}
    # host A: the run's router (listening on the link), recorder, simulator, r1 and r3
    run = subprocess.Popen(["ip", "netns", "exec", a, sys.executable, "-m", "orchestrator", "run", str(config("e5.5-")),
                            "--out", str(tmp_path), "--run-id", "hosts", "--duration", "40",
                            "--listen", "tcp/10.77.0.1:7447", "--external", "r2", "-q", "--no-plots"],
                           cwd=str(REPO), env={**os.environ, **env}, start_new_session=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    procs.started.append(run)
    # host B: its own router, connected to A's, and r2 connected to B's router
    router_b = subprocess.Popen(["ip", "netns", "exec", b, sys.executable, "-c", _ROUTER, "tcp/10.77.0.2:7447",
                                 "tcp/10.77.0.1:7447"], cwd=str(REPO), env={**os.environ, **env},
                                start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    procs.started.append(router_b)
    assert router_b.stdout.readline().decode().strip() == "router up"
    scen = tmp_path / "scenario.json"
    deadline = time.monotonic() + 60
    while not scen.is_file():
        assert run.poll() is None and time.monotonic() < deadline, run.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    r2 = subprocess.Popen(["ip", "netns", "exec", b, sys.executable, "-m", "agent", "--run-id", "hosts", "--robot", "r2",
                           "--config", str(scen), "--connect", "tcp/10.77.0.2:7447"],
                          cwd=str(REPO), env={**os.environ, **env}, start_new_session=True,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    procs.started.append(r2)
    assert run.wait(timeout=240) == 0, run.stderr.read().decode()[-3000:]
    assert r2.wait(timeout=30) == 0, r2.stderr.read().decode()[-2000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["ok"] and m["fleet"]["coordination_error_max_m"] < 0.02
    log = read_log(tmp_path / "run.mcap")
    ticks = log.counts["copath/hosts/sim/truth"]
    assert ticks == 400
    for n in ("r1", "r2", "r3"):  # every robot is in the record, r2 through both routers
        assert log.counts[f"copath/hosts/robot/{n}/cmd"] == ticks
        assert f"copath/hosts/peer/{n}/all" in log.counts
