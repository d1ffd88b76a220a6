"""The fault layer on a network without faults releases every message at its stamp: the
same release times as the general path (which draws per message for the fault decisions),
without the draws (docs/journal/performance.md, profile of E6.1 (P11))."""

import numpy as np

from copath.scenario import NetworkConfig
from copath.wire.faults import FaultyInbox, LinkFaults


def test_clean_network_releases_at_the_stamp_like_the_general_path():
    net = NetworkConfig()
    fast, general = LinkFaults(net, 1, "r1"), LinkFaults(net, 1, "r1")
    general._clean = False  # the general path, with its draws
    rng = np.random.default_rng(0)
    for _ in range(500):
        sender, stamp = f"r{rng.integers(2, 6)}", float(rng.uniform(0, 100))
        assert fast.release_time(sender, stamp) == general.release_time(sender, stamp) == stamp
    assert fast.dropped == general.dropped == 0


def test_any_fault_takes_the_general_path():
    for net in (NetworkConfig(loss=0.5), NetworkConfig(delay_ms=50.0), NetworkConfig(jitter_ms=5.0),
                NetworkConfig(burst_p_gb=0.2)):
        faults = LinkFaults(net, 1, "r1")
        out = [faults.release_time("r2", 0.1 * k) for k in range(200)]
        assert any(r is None or r > 0.1 * k for k, r in enumerate(out)), net  # dropped or delayed
    inbox = FaultyInbox(LinkFaults(NetworkConfig(), 1, "r1"))
    assert all(inbox.push("r2", 0.1 * k, k) for k in range(10))
    assert inbox.pop_ready(1.0) == list(range(10))  # never one stamped at now itself
