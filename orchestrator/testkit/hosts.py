"""Two "hosts" on one machine: Linux network namespaces joined by a veth pair, each with
its own Zenoh router (docs/reference/faults.md, "Across hosts"), and E5.5 fleets run across
them. Shared by the netns and router tests and by ``orchestrator/studies/bench/fault_table.py``.

Host A is 10.77.0.1, host B 10.77.0.2 on their own /24. Setting them up needs root and
``ip netns``; an impairment of the link needs ``tc`` (rate limit) or ``iptables`` (random
drop with the ``statistic`` match). :func:`why_not` names what is missing."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass
from typing import Callable, Iterator

from orchestrator.log.mcap import read_log

from .processes import REPO, child_env
from .scenarios import config

ADDR_A, ADDR_B = "10.77.0.1", "10.77.0.2"
PORT = 7447


def endpoint(addr: str, port: int = PORT) -> str:
    return f"tcp/{addr}:{port}"


def _run(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, timeout=20)


def why_not(*, iptables: bool = False, tc: bool = False) -> str | None:
    """Why two hosts cannot be set up here (None: they can)."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    if iptables and shutil.which("iptables") is None:
        return "iptables is not installed (random packet drop needs its statistic match)"
    if tc and shutil.which("tc") is None:
        return "tc (iproute2) is not installed"
    probe = f"cpprobe{os.getpid()}"
    res = _run(["ip", "netns", "add", probe])
    if res.returncode != 0:
        return f"ip netns add is not permitted here: {res.stderr.strip()}"
    try:
        if iptables:
            res = _run(["ip", "netns", "exec", probe, "iptables", "-A", "INPUT", "-m", "statistic", "--mode", "random",
                        "--probability", "0.1", "-j", "DROP"])
            if res.returncode != 0:
                return f"iptables with the statistic match does not work in a namespace: {res.stderr.strip()}"
    finally:
        _run(["ip", "netns", "del", probe])
    return None


@dataclass(frozen=True)
class Hosts:
    a: str
    """Namespace of host A."""
    b: str
    """Namespace of host B."""
    dev_a: str
    dev_b: str

    def argv(self, host: str, argv: list[str]) -> list[str]:
        """``argv`` run inside ``host``'s namespace (``ip netns exec`` execs it: same pid)."""
        return ["ip", "netns", "exec", host, *argv]

    def drop(self, host: str, probability: float) -> None:
        """Drop this share of the packets arriving at ``host`` over the link (iptables,
        statistic random match; the loopback traffic inside the host is untouched)."""
        dev = self.dev_a if host == self.a else self.dev_b
        res = _run(self.argv(host, ["iptables", "-A", "INPUT", "-i", dev, "-m", "statistic", "--mode", "random",
                                    "--probability", str(probability), "-j", "DROP"]))
        if res.returncode != 0:
            raise RuntimeError(f"iptables drop on {host}: {res.stderr.strip()}")

    def dropped(self, host: str) -> int:
        """Packets the drop rule on ``host`` has dropped so far."""
        res = _run(self.argv(host, ["iptables", "-L", "INPUT", "-v", "-n", "-x"]))
        return sum(int(line.split()[0]) for line in res.stdout.splitlines()[2:] if "DROP" in line)

    def throttle(self, host: str, rate: str = "4mbit") -> None:
        """A token-bucket rate limit (``tc tbf``) on ``host``'s side of the link."""
        dev = self.dev_a if host == self.a else self.dev_b
        res = _run(self.argv(host, ["tc", "qdisc", "add", "dev", dev, "root", "tbf", "rate", rate,
                                    "burst", "32kbit", "latency", "50ms"]))
        if res.returncode != 0:
            raise RuntimeError(f"tc tbf on {host}: {res.stderr.strip()}")


@contextlib.contextmanager
def two_hosts(on_setup_error: Callable[[str], None] | None = None) -> Iterator[Hosts]:
    """Set up hosts A and B, torn down on exit. A step that fails calls
    ``on_setup_error(message)`` (e.g. ``pytest.skip``), else raises RuntimeError."""
    tag = uuid.uuid4().hex[:6]
    h = Hosts(f"cpA{tag}", f"cpB{tag}", f"va{tag}", f"vb{tag}")
    try:
        for cmd in (["netns", "add", h.a], ["netns", "add", h.b],
                    ["link", "add", h.dev_a, "type", "veth", "peer", "name", h.dev_b],
                    ["link", "set", h.dev_a, "netns", h.a], ["link", "set", h.dev_b, "netns", h.b],
                    ["-n", h.a, "addr", "add", f"{ADDR_A}/24", "dev", h.dev_a],
                    ["-n", h.b, "addr", "add", f"{ADDR_B}/24", "dev", h.dev_b],
                    ["-n", h.a, "link", "set", h.dev_a, "up"], ["-n", h.b, "link", "set", h.dev_b, "up"],
                    ["-n", h.a, "link", "set", "lo", "up"], ["-n", h.b, "link", "set", "lo", "up"]):
            res = _run(["ip", *cmd])
            if res.returncode != 0:
                msg = f"ip {' '.join(cmd)} failed: {res.stderr.strip()}"
                if on_setup_error is not None:
                    on_setup_error(msg)
                raise RuntimeError(msg)
        yield h
    finally:
        _run(["ip", "netns", "del", h.a])  # deletes the veth pair with it
        _run(["ip", "netns", "del", h.b])


ROUTER = """
import signal, sys, time
from copath.wire.session import SessionConfig, ZenohLink
listen, lease_ms, connect = sys.argv[1], int(sys.argv[2]), tuple(sys.argv[3:])
link = ZenohLink.open(SessionConfig(mode="router", listen=(listen,), connect=connect, lease_ms=lease_ms))
print("router up", flush=True)
signal.signal(signal.SIGTERM, lambda *a: sys.exit(0))
try:
    while True:
        time.sleep(0.2)
finally:
    link.close()
"""
"""A host's own Zenoh router: ``python -c ROUTER LISTEN LEASE_MS [CONNECT...]``."""



def popen(hosts: Hosts, host: str, argv: list[str], log=None) -> subprocess.Popen:
    """A Python program in ``host``'s namespace, in its own process group (kill by pid);
    its output goes to pipes, or to the file ``log``."""
    out = subprocess.PIPE if log is None else open(log, "wb")
    try:
        return subprocess.Popen(hosts.argv(host, [sys.executable, *argv]), cwd=str(REPO), env=child_env(),
                                start_new_session=True, stdout=out, stderr=subprocess.STDOUT if log else out)
    finally:
        if log is not None:
            out.close()


def start_router(hosts: Hosts, host: str, listen: str, *connect: str, lease_ms: int = 1000,
                 timeout_s: float = 60.0) -> subprocess.Popen:
    """Start ``host``'s router (announcing a transport lease of ``lease_ms``) and wait until it is up."""
    p = popen(hosts, host, ["-c", ROUTER, listen, str(lease_ms), *connect])
    deadline = time.monotonic() + timeout_s
    line = p.stdout.readline().decode().strip()  # blocks until the router prints or exits
    if line != "router up" or time.monotonic() > deadline:
        p.kill()
        raise RuntimeError(f"the router on {host} did not start: {p.stderr.read().decode()[-1000:]}")
    return p


def wait_for_file(path, proc: subprocess.Popen, timeout_s: float = 120.0) -> None:
    """Wait for ``path`` to exist while ``proc`` runs."""
    deadline = time.monotonic() + timeout_s
    while not path.is_file():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise AssertionError(f"{path.name} did not appear: {proc.stderr.read().decode()[-2000:]}")
        time.sleep(0.05)


def stop_all(procs) -> None:
    """Stop every process a test started: SIGTERM to each group first (an orchestrator then
    stops its own children and finishes its log), SIGKILL to what is left (``procs.cleanup``)."""
    running = [p for p in procs.started if p.poll() is None]
    for p in running:
        try:
            os.killpg(p.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + 15.0
    for p in running:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    procs.cleanup()


# -- fleets across the two hosts ----------------------------------------------------------

DROP = 0.3
"""Share of the packets arriving at host A that the netns fault drops."""
LEASE_MS = 10000
"""Transport lease host B's router announces on a lossy link (docs/reference/faults.md, "Across hosts")."""
REMOTE = ("r2", "r3")
"""The robots :func:`kill_remote_router` runs on host B."""


def run_across_hosts(tmp_path, procs, hosts, run_id: str, duration_s: float = 40.0):
    """E5.5 with the run's router, recorder, simulator, r1 and r3 on host A and r2 on host B
    behind B's own router (connected to A's). Returns (orchestrator, r2) once both exited."""
    run = popen(hosts, hosts.a, ["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path),
                                 "--run-id", run_id, "--duration", str(duration_s), "--listen", endpoint(ADDR_A),
                                 "--external", "r2", "-q", "--no-plots", "--no-secure"])  # a site router logs in as nobody (README)
    procs.started.append(run)
    procs.started.append(start_router(hosts, hosts.b, endpoint(ADDR_B), endpoint(ADDR_A), lease_ms=LEASE_MS))
    wait_for_file(tmp_path / "scenario.json", run)
    r2_log = tmp_path / "logs" / "r2.log"  # the run's own logs are beside it
    r2 = popen(hosts, hosts.b, ["-m", "agent", "--run-id", run_id, "--robot", "r2",
                                "--config", str(tmp_path / "scenario.json"), "--connect", endpoint(ADDR_B)], log=r2_log)
    procs.started.append(r2)
    assert run.wait(timeout=240) == 0, run.stderr.read().decode()[-3000:] + r2_log.read_text()[-2000:]
    assert r2.wait(timeout=30) == 0, r2_log.read_text()[-2000:]
    return run, r2


def kill_remote_router(tmp_path, procs, hosts, policy: str, run_id: str = "router", duration_s: float = 60.0) -> dict:
    """E5.5 with r1 on host A and r2, r3 on host B; B's router is killed once the run is under
    way. Returns the orchestrator's exit code and stderr, metrics.json, the read-back log and
    the detection time (kill to the simulator's ``robot_lost`` event or, under ``fail``, its
    ``End``) in seconds."""
    router_b = start_router(hosts, hosts.b, endpoint(ADDR_B))
    procs.started.append(router_b)
    run = popen(hosts, hosts.a, ["-m", "orchestrator", "run", str(config("e5.5-")), "--out", str(tmp_path),
                                 "--run-id", run_id, "--duration", str(duration_s), "--listen", endpoint(ADDR_A),
                                 "--connect", endpoint(ADDR_B), *[a for n in REMOTE for a in ("--external", n)],
                                 "--on-robot-failure", policy, "-q", "--no-plots", "--no-secure"])  # a site router logs in as nobody (README)
    procs.started.append(run)
    wait_for_file(tmp_path / "scenario.json", run)
    for n in REMOTE:
        procs.started.append(popen(hosts, hosts.b, ["-m", "agent", "--run-id", run_id, "--robot", n, "--config",
                                                    str(tmp_path / "scenario.json"), "--connect", endpoint(ADDR_B)]))
    mcap = tmp_path / "run.mcap"
    deadline = time.monotonic() + 150
    while not (mcap.is_file() and mcap.stat().st_size > 200_000):  # the run is under way
        assert run.poll() is None and time.monotonic() < deadline, run.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    t_kill = time.time_ns()
    os.kill(router_b.pid, signal.SIGKILL)
    rc = run.wait(timeout=240)
    stderr = run.stderr.read().decode()
    log = read_log(mcap)
    if policy == "fail":
        marks = [t for t, _, r in log.records if getattr(r, "TYPE", "") == "end"]
    else:
        marks = [t for t, _, r in log.records if getattr(r, "TYPE", "") == "event" and r.what == "robot_lost"]
    detection = [(t - t_kill) / 1e9 for t in marks]
    return {"rc": rc, "stderr": stderr, "metrics": json.loads((tmp_path / "metrics.json").read_text()), "log": log,
            "detection_s": max(detection) if detection else None}
