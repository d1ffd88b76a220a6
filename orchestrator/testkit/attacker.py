"""A Zenoh session that is not one of the run's processes: it publishes forgeries onto a
running fleet's keys, or tries to join a secure run (docs/reference/faults.md)."""

from __future__ import annotations

import time

from copath.wire.keys import Keys
from copath.wire.session import SessionConfig, ZenohLink


def attacker(endpoint: str) -> ZenohLink:
    """A client session to the run's router at ``endpoint``, no credentials; it gives up
    after 60 s instead of waiting for the router forever."""
    return ZenohLink.open(SessionConfig(mode="client", connect=(endpoint,), extra=(("connect/timeout_ms", "60000"),)))


def session(endpoint: str, config_file=None, timeout_ms: int = 3000) -> ZenohLink:
    """A client session to ``endpoint`` with the Zenoh configuration ``config_file`` (e.g. a
    robot's credentials), giving up after ``timeout_ms``."""
    return ZenohLink.open(SessionConfig(mode="client", connect=(endpoint,), config_file=config_file,
                                        extra=(("connect/timeout_ms", str(timeout_ms)),)))


def wait_for_truth(link: ZenohLink, keys: Keys, ticks: int, proc, timeout_s: float = 150.0) -> None:
    """Wait until ``link`` heard ``ticks`` truth records of the run (it is under way) while
    the orchestrator ``proc`` runs."""
    seen = []
    link.subscribe_raw(keys.truth, lambda k, b: seen.append(1))
    deadline = time.monotonic() + timeout_s
    while len(seen) < ticks:
        assert proc.poll() is None, proc.stderr.read().decode()[-3000:]
        assert time.monotonic() < deadline, "the run did not start"
        time.sleep(0.05)
