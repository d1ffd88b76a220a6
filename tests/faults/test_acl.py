"""Secure mode's access policy (copath.wire.acl): what each process may do, the in-process
bus enforcing it on every bundled scenario, and the run's Zenoh router agreeing with it.

The router refuses a subscription silently; a fleet whose robot subscribes outside its
grants then waits for messages that never come (a leader-following fleet stalled this way
while its safety filter's overhearing was not granted). The in-process bus raises instead,
so every in-process run checks the grants."""

from __future__ import annotations

import pathlib
import time

import pytest

from copath.scenario import load_scenario
from copath.wire.acl import AccessDenied, AccessPolicy, grants
from copath.wire.keys import Keys
from copath.wire.link import MemoryBus
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint
from orchestrator.run.inprocess import run_scenario
from orchestrator.run.security import client_extra, make_credentials, router_extra
from tests.conftest import CONFIGS

KEYS = Keys("acl")


def test_each_process_may_use_only_its_own_keys():
    pol = AccessPolicy(KEYS)
    assert pol.allows("r1", "publish", KEYS.cmd("r1")) and not pol.allows("r1", "publish", KEYS.cmd("r2"))
    assert pol.allows("r1", "publish", KEYS.peer_direct("r1", "r2"))
    assert not pol.allows("r1", "publish", KEYS.peer_broadcast("r2"))
    assert not pol.allows("r1", "publish", KEYS.obs("r1")) and not pol.allows("r1", "publish", KEYS.end)
    assert pol.allows("sim", "publish", KEYS.obs("r1")) and pol.allows("sim", "publish", KEYS.end)
    assert not pol.allows("sim", "publish", KEYS.cmd("r1"))
    assert pol.allows("r1", "subscribe", KEYS.obs("r1")) and not pol.allows("r1", "subscribe", KEYS.obs("r2"))
    assert not pol.allows("r1", "subscribe", KEYS.truth) and not pol.allows("r1", "subscribe", KEYS.all)
    assert pol.allows("r1", "token", KEYS.alive("r1")) and not pol.allows("r1", "token", KEYS.alive("sim"))
    assert pol.allows("r1", "watch", KEYS.all_alive)


def test_a_subscription_must_be_included_whole_in_a_grant():
    """Zenoh's rule: some covered keys being granted is not enough."""
    closed, open_ = AccessPolicy(KEYS), AccessPolicy(KEYS, overhear=True)
    everyone = KEYS.peer_direct("*", "*")
    assert closed.allows("r1", "subscribe", KEYS.peer_direct("*", "r1"))
    assert not closed.allows("r1", "subscribe", everyone)
    assert open_.allows("r1", "subscribe", everyone)  # the safety filter overhears
    assert not open_.allows("r1", "subscribe", f"{KEYS.prefix}/peer/**")
    assert grants(KEYS, "sim", overhear=True) == grants(KEYS, "sim")


def test_a_link_stepping_outside_its_grants_fails_naming_the_key_and_what_is_allowed():
    bus = MemoryBus(policy=AccessPolicy(KEYS))
    r1 = bus.link("r1")
    with pytest.raises(AccessDenied, match=r"r1 may not publish on 'copath/acl/robot/r2/cmd'.*robot/r1/cmd"):
        r1.publish(KEYS.cmd("r2"), object())
    with pytest.raises(AccessDenied, match="r1 may not subscribe to"):
        r1.subscribe(KEYS.truth, lambda k, r: None)
    with pytest.raises(ValueError, match="action = 'read' is not allowed"):
        AccessPolicy(KEYS).allows("r1", "read", KEYS.cmd("r1"))
    unchecked = MemoryBus().link("r1")  # a bus without a policy checks nothing
    unchecked.publish(KEYS.cmd("r2"), object())
    assert unchecked.published == 1 and bus.records == []


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("e*.toml")), ids=lambda p: p.stem)
def test_every_bundled_scenario_runs_within_its_grants(path: pathlib.Path):
    """Every node of every bundled scenario subscribes, declares and publishes only what
    secure mode grants it (the in-process bus raises otherwise), for its first ticks."""
    scen = load_scenario(path)
    ticks = 5
    res = run_scenario(scen, duration_s=ticks * scen.run.dt, run_id="acl")
    keys = {k for _, k, _ in res.records}
    for r in scen.robot_names:
        assert KEYS.cmd(r) in keys and KEYS.obs(r) in keys
    if len(scen.robot_names) > 1:  # the robots talked to each other
        assert any("/peer/" in k for k in keys)


@pytest.mark.fleet
@pytest.mark.timeout(60)
@pytest.mark.parametrize("overhear", [False, True])
def test_the_router_refuses_and_grants_what_the_policy_does(tmp_path, overhear):
    """The run's router (orchestrator/run/security.py) enforces the same grants: a robot's
    ``peer/*/to/*`` subscription hears other robots' direct messages only when overhearing
    is granted, and its own ``peer/*/to/r2`` one hears its messages either way."""
    robots = ["r1", "r2", "r3"]
    creds = make_credentials(tmp_path / "secrets", ["sim", *robots])
    ep = loopback_endpoint(free_port())

    def client(user: str) -> ZenohLink:
        return ZenohLink.open(SessionConfig(mode="client", connect=(ep,), extra=client_extra(user, creds.users[user])))

    heard: dict[str, list[str]] = {"all": [], "mine": []}
    with ZenohLink.open(SessionConfig(mode="router", listen=(ep,),
                                      extra=router_extra(creds, KEYS, robots, overhear=overhear))), \
            client("r1") as r1, client("r2") as r2:
        r2.session.declare_subscriber(KEYS.peer_direct("*", "*"), lambda s: heard["all"].append(str(s.key_expr)))
        r2.session.declare_subscriber(KEYS.peer_direct("*", "r2"), lambda s: heard["mine"].append(str(s.key_expr)))
        time.sleep(0.5)
        for _ in range(10):
            r1.publish_bytes(KEYS.peer_direct("r1", "r3"), b"x")
            r1.publish_bytes(KEYS.peer_direct("r1", "r2"), b"x")
            time.sleep(0.01)
        deadline = time.monotonic() + 5
        while len(heard["mine"]) < 10 and time.monotonic() < deadline:
            time.sleep(0.02)
    policy = AccessPolicy(KEYS, overhear=overhear)
    assert len(heard["mine"]) == 10
    assert policy.allows("r2", "subscribe", KEYS.peer_direct("*", "*")) == overhear
    # the router forwards r1 -> r3 only with the grant (the session hands what it does
    # receive, r1 -> r2, to every local subscriber that matches)
    assert (KEYS.peer_direct("r1", "r3") in heard["all"]) == overhear
    assert len(heard["all"]) == (20 if overhear else 10)


def test_a_secure_session_stepping_outside_its_grants_fails_at_once():
    """Behind a secure router the agent and the simulator guard their own link: what the
    router would refuse without a word raises here, naming the key."""
    from copath.wire.session import ZenohLink

    with ZenohLink.open(SessionConfig(mode="peer", listen=(loopback_endpoint(free_port()),))) as link:
        link.guard(AccessPolicy(KEYS), "r1")
        link.subscribe(KEYS.obs("r1"), lambda k, r: None)
        link.declare_token(KEYS.alive("r1"))
        with pytest.raises(AccessDenied, match="r1 may not subscribe to 'copath/acl/peer/\\*/to/\\*'"):
            link.subscribe(KEYS.peer_direct("*", "*"), lambda k, r: None)
        with pytest.raises(AccessDenied, match="r1 may not publish on"):
            link.publish_bytes(KEYS.obs("r1"), b"x")
        with pytest.raises(AccessDenied, match="r1 may not declare the liveliness token 'copath/acl/alive/r2'"):
            link.declare_token(KEYS.alive("r2"))
        assert link.published == 0
