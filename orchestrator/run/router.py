"""The run's Zenoh router, in the orchestrator's process, with the run's credentials.

It listens on a free loopback port (or ``--listen``), connects to other hosts' routers
(``--connect``), announces the scenario's transport lease (``run.lease_s``) and, in secure
mode, admits each process with its own credentials and access control
(``orchestrator/run/security.py``, docs/reference/faults.md)."""

from __future__ import annotations

import logging
import pathlib

from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.session import SessionConfig, ZenohLink, free_port, loopback_endpoint

logger = logging.getLogger(__name__)

__all__ = ["RunRouter"]


class RunRouter:
    """The run's router and the endpoints and credentials its processes connect with."""

    def __init__(self, scenario: Scenario, keys: Keys, secrets_dir: pathlib.Path, secure: bool,
                 listen: tuple[str, ...] = (), connect: tuple[str, ...] = ()) -> None:
        self.listen = tuple(listen) or (loopback_endpoint(free_port()),)
        """The endpoints the router listens on (default: one free loopback port)."""
        self.children_connect = [e.replace("0.0.0.0", "127.0.0.1") for e in self.listen]
        """What the processes started here connect to."""
        self.creds = None
        extra = ()
        if secure:
            from copath.wire.acl import overhears  # noqa: PLC0415

            from orchestrator.run.security import make_credentials, router_extra  # noqa: PLC0415

            self.creds = make_credentials(secrets_dir, ["sim", *scenario.robot_names])
            extra = router_extra(self.creds, keys, list(scenario.robot_names), overhear=overhears(scenario))
            if connect:
                logger.warning("secure mode: robots that join through the routers of --connect are refused "
                               "(a router in between logs in as nobody); use --no-secure for such a fleet "
                               "(README, 'Running robots on several machines')")
        self.link = ZenohLink.open(SessionConfig(mode="router", listen=self.listen, connect=tuple(connect),
                                                 lease_ms=round(1e3 * scenario.run.lease_s), extra=extra))
        """The router's own session: the recorder and the orchestrator's watchers subscribe on it."""

    def auth(self, proc: str) -> list[str]:
        """Command-line arguments giving process ``proc`` its credentials (a file only its
        owner reads); none on an open bus."""
        return ["--zenoh-config", str(self.creds.process_file(proc).resolve())] if self.creds is not None else []

    def close(self) -> None:
        self.link.close()
