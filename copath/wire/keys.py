"""Key expressions of a run: everything lives under ``copath/<run_id>/``.

Two runs with different ids never share a key, and each run also has its own router
port (``copath.wire.session``), so they never hear each other.
"""

from __future__ import annotations

import re

__all__ = ["Keys", "valid_run_id", "ROOT"]

ROOT = "copath"
_ID = re.compile(r"^[A-Za-z0-9_\-.]+$")


def valid_run_id(run_id: str) -> str:
    """Return run_id if it is a single key chunk (letters, digits, ``_-.``), else raise."""
    if not isinstance(run_id, str) or not _ID.match(run_id) or run_id in (".", ".."):
        raise ValueError(f"run id = {run_id!r} is not allowed; use letters, digits, '_', '-', '.'")
    return run_id


class Keys:
    """Key expressions of one run."""

    def __init__(self, run_id: str) -> None:
        self.run_id = valid_run_id(run_id)
        self.prefix = f"{ROOT}/{run_id}"

    # everything of the run (the recorder's subscription)
    @property
    def all(self) -> str:
        return f"{self.prefix}/**"

    # simulator
    @property
    def start(self) -> str:
        return f"{self.prefix}/sim/start"

    @property
    def truth(self) -> str:
        return f"{self.prefix}/sim/truth"

    @property
    def end(self) -> str:
        return f"{self.prefix}/sim/end"

    def event(self, proc: str) -> str:
        return f"{self.prefix}/{proc}/event"

    # one robot
    def obs(self, robot: str) -> str:
        return f"{self.prefix}/robot/{robot}/obs"

    def cmd(self, robot: str) -> str:
        return f"{self.prefix}/robot/{robot}/cmd"

    @property
    def all_cmds(self) -> str:
        return f"{self.prefix}/robot/*/cmd"

    def telemetry(self, robot: str) -> str:
        return f"{self.prefix}/robot/{robot}/telemetry"

    def estimate(self, robot: str) -> str:
        return f"{self.prefix}/robot/{robot}/estimate"

    # robot -> robot
    def peer_broadcast(self, sender: str) -> str:
        return f"{self.prefix}/peer/{sender}/all"

    def peer_direct(self, sender: str, receiver: str) -> str:
        return f"{self.prefix}/peer/{sender}/to/{receiver}"

    def peer_subscriptions(self, robot: str, neighbours: tuple[str, ...] | None) -> list[str]:
        """What robot subscribes to: its neighbours' broadcasts and messages to it;
        ``neighbours=None`` (range-limited graph) means every robot."""
        if neighbours is None:
            return [f"{self.prefix}/peer/*/all", f"{self.prefix}/peer/*/to/{robot}"]
        out = []
        for n in neighbours:
            out += [self.peer_broadcast(n), self.peer_direct(n, robot)]
        return out

    # liveliness and closing accounts
    def alive(self, proc: str) -> str:
        return f"{self.prefix}/alive/{proc}"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/*"

    def stats(self, proc: str) -> str:
        return f"{self.prefix}/stats/{proc}"

    def relative(self, key: str) -> str:
        """Key without the run prefix (``robot/r1/obs``)."""
        return key[len(self.prefix) + 1 :] if key.startswith(self.prefix + "/") else key
