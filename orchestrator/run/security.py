"""Secure mode (``run.secure``, ``--secure``): per-run credentials and access control.

The orchestrator makes a fresh user name and random password for every process of a run
(the simulator and each robot), writes them into the run's ``secrets/`` directory
(readable by the owner only), and opens the run's router with Zenoh's user/password
authentication and an access-control list that denies everything not granted.
The grants themselves (who may publish, subscribe to, declare and watch which keys) are
:func:`copath.wire.acl.grants`, the one policy the router here and the in-process bus both
enforce. A session without credentials, or with a wrong password, is refused when it
connects; a session with a robot's credentials can do only what that robot may. The
recorder is the router's own session, so it hears everything. Why user/password and not
TLS, and what secure mode costs: docs/reference/security.md.
"""

from __future__ import annotations

import json
import os
import pathlib
import secrets
from dataclasses import dataclass

from copath.wire.acl import grants
from copath.wire.keys import Keys

__all__ = ["RunCredentials", "make_credentials", "acl_config", "router_extra", "client_extra"]

_PUT = ["put", "delete"]
_SUB = ["declare_subscriber"]
_TOKEN = ["liveliness_token"]
_WATCH = ["declare_liveliness_subscriber", "liveliness_query"]


@dataclass(frozen=True)
class RunCredentials:
    """User names and passwords of one run's processes, and where they are written."""

    users: dict[str, str]
    """Process name (``sim`` or a robot) -> password; the user name is the process name."""
    directory: pathlib.Path
    """``DIR/secrets``: ``credentials.txt`` for the router, ``<proc>.json`` per process."""

    @property
    def dictionary_file(self) -> pathlib.Path:
        return self.directory / "credentials.txt"

    def process_file(self, proc: str) -> pathlib.Path:
        """The Zenoh config fragment a process starts from (``--zenoh-config``)."""
        return self.directory / f"{proc}.json5"


def _write_private(path: pathlib.Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)


def make_credentials(directory: pathlib.Path, procs: list[str]) -> RunCredentials:
    """Fresh random passwords for ``procs``, written owner-readable only into ``directory``."""
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    users = {p: secrets.token_urlsafe(24) for p in procs}
    creds = RunCredentials(users, directory)
    _write_private(creds.dictionary_file, "".join(f"{u}:{pw}\n" for u, pw in users.items()))
    for proc, pw in users.items():
        _write_private(creds.process_file(proc),
                       json.dumps({"transport": {"auth": {"usrpwd": {"user": proc, "password": pw}}}}, indent=1))
    return creds


def acl_config(keys: Keys, robots: list[str], overhear: bool = False) -> dict:
    """The router's ``access_control`` block: deny by default, grant per process.

    ``overhear`` (the scenario's safety filter overhears, ``safety.overhear``): a robot may
    also read the direct messages between other robots, whose sender positions its filter
    uses. Without the grant the router refuses the filter's ``peer/*/to/*`` subscription as
    a whole, and with it every peer message the robot would receive through it."""
    rules, subjects, policies = [], [], []
    for proc in ["sim", *robots]:
        g = grants(keys, proc, overhear)
        pub, sub = list(g.publish), list(g.subscribe)
        rules += [
            {"id": f"{proc}-pub", "permission": "allow", "flows": ["ingress"], "messages": _PUT, "key_exprs": pub},
            # the router tells a publisher who subscribes to its keys (else it would not send)
            {"id": f"{proc}-heard", "permission": "allow", "flows": ["egress"], "messages": _SUB, "key_exprs": pub},
            {"id": f"{proc}-sub", "permission": "allow", "flows": ["ingress"], "messages": _SUB, "key_exprs": sub},
            {"id": f"{proc}-recv", "permission": "allow", "flows": ["egress"], "messages": _PUT, "key_exprs": sub},
            {"id": f"{proc}-token", "permission": "allow", "flows": ["ingress"], "messages": _TOKEN,
             "key_exprs": list(g.token)},
            {"id": f"{proc}-watch", "permission": "allow", "flows": ["ingress"], "messages": _WATCH,
             "key_exprs": list(g.watch)},
            {"id": f"{proc}-seen", "permission": "allow", "flows": ["egress"], "messages": _TOKEN + ["reply"],
             "key_exprs": list(g.watch)},
        ]
        subjects.append({"id": f"{proc}-subject", "usernames": [proc]})
        policies.append({"id": f"{proc}-policy",
                         "rules": [f"{proc}-{x}" for x in ("pub", "heard", "sub", "recv", "token", "watch", "seen")],
                         "subjects": [f"{proc}-subject"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def router_extra(creds: RunCredentials, keys: Keys, robots: list[str],
                 overhear: bool = False) -> tuple[tuple[str, str], ...]:
    """Zenoh config entries of the run's router in secure mode."""
    return (("transport/auth/usrpwd", json.dumps({"dictionary_file": str(creds.dictionary_file)})),
            ("access_control", json.dumps(acl_config(keys, robots, overhear))))


def client_extra(user: str, password: str) -> tuple[tuple[str, str], ...]:
    """Zenoh config entries of a client that authenticates as ``user``."""
    return (("transport/auth/usrpwd", json.dumps({"user": user, "password": password})),)
