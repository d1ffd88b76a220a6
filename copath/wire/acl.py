"""Who may do what on a run's bus: the access policy of secure mode (docs/reference/security.md).

One policy, two enforcers. The run's Zenoh router enforces it in a secure fleet
(``orchestrator/run/security.py`` turns :func:`grants` into Zenoh's ``access_control``
block), and the in-process bus enforces it in every in-process run
(:class:`copath.wire.link.MemoryBus` with a :class:`AccessPolicy`), where a node that
publishes or subscribes outside its grants raises :class:`AccessDenied` at once instead
of waiting, as it would behind the router, for messages the router silently refuses.

=============  =========================================================================
process        may publish (put)                       may subscribe to (and receive)
=============  =========================================================================
``sim``        ``sim/**``, ``robot/*/obs``,            ``robot/*/cmd``, ``robot/*/telemetry``
               ``stats/sim``
robot ``r``    ``robot/r/cmd|telemetry|estimate``,     ``robot/r/obs``, ``sim/start``,
               ``peer/r/**``, ``r/event``, ``stats/r`` ``sim/end``, ``peer/*/all``,
                                                       ``peer/*/to/r`` (``peer/*/to/*`` when
                                                       the safety filter overhears)
=============  =========================================================================

Liveliness: each process may declare only ``alive/<itself>`` and watch ``alive/*``.
A subscription is allowed when a grant *includes* its whole key expression (Zenoh's rule:
``peer/*/to/*`` is refused to a robot granted ``peer/*/to/r``, even though some of the
keys it covers are granted).
"""

from __future__ import annotations

from dataclasses import dataclass

import zenoh

from .keys import Keys

__all__ = ["Grants", "grants", "overhears", "AccessPolicy", "AccessDenied", "ACTIONS"]

ACTIONS = ("publish", "subscribe", "token", "watch")
_VERBS = {"publish": "publish on", "subscribe": "subscribe to", "token": "declare the liveliness token",
          "watch": "watch the liveliness of"}


class AccessDenied(PermissionError):
    """A node published or subscribed outside its grants."""


@dataclass(frozen=True)
class Grants:
    """Key expressions one process may use, per action."""

    publish: tuple[str, ...]
    subscribe: tuple[str, ...]
    token: tuple[str, ...]
    watch: tuple[str, ...]


def grants(keys: Keys, proc: str, overhear: bool = False) -> Grants:
    """What ``proc`` (``sim`` or a robot name) may do; ``overhear``: robots may also read
    the direct messages between other robots, whose sender positions the safety filter
    uses (``safety.enabled`` and ``safety.overhear``)."""
    if proc == "sim":
        pub = (f"{keys.prefix}/sim/**", f"{keys.prefix}/robot/*/obs", keys.stats("sim"))
        sub = (keys.all_cmds, f"{keys.prefix}/robot/*/telemetry")
    else:
        r = proc
        pub = (keys.cmd(r), keys.telemetry(r), keys.estimate(r), f"{keys.prefix}/peer/{r}/**", keys.event(r),
               keys.stats(r))
        sub = (keys.obs(r), keys.start, keys.end, keys.peer_broadcast("*"),
               keys.peer_direct("*", "*" if overhear else r))
    return Grants(pub, sub, (keys.alive(proc),), (keys.all_alive,))


def overhears(scenario) -> bool:
    """Does ``scenario``'s safety filter overhear other robots' messages (the grant of
    ``peer/*/to/*`` to robots)? ``safety.enabled`` and ``safety.overhear``."""
    return bool(scenario.safety.enabled and scenario.safety.overhear)


class AccessPolicy:
    """The grants of every process of a run, checked per (process, action, key expression).

    Answers are cached: a run uses a few keys per process, so after the first message on a
    key a check is one dictionary look-up."""

    def __init__(self, keys: Keys, overhear: bool = False) -> None:
        self.keys = keys
        self.overhear = overhear
        self._grants: dict[str, Grants] = {}
        self._seen: dict[tuple[str, str, str], bool] = {}

    @classmethod
    def for_scenario(cls, keys: Keys, scenario) -> "AccessPolicy":
        """The policy of a run of ``scenario`` (what its router grants in secure mode)."""
        return cls(keys, overhear=overhears(scenario))

    def grants_of(self, proc: str) -> Grants:
        g = self._grants.get(proc)
        if g is None:
            g = self._grants[proc] = grants(self.keys, proc, self.overhear)
        return g

    def allows(self, proc: str, action: str, key_expr: str) -> bool:
        """True when one of ``proc``'s grants for ``action`` includes all of ``key_expr``."""
        memo = (proc, action, key_expr)
        ok = self._seen.get(memo)
        if ok is None:
            if action not in ACTIONS:
                raise ValueError(f"action = {action!r} is not allowed; allowed: {', '.join(ACTIONS)}")
            ke = zenoh.KeyExpr(key_expr)
            ok = self._seen[memo] = any(zenoh.KeyExpr(g).includes(ke)
                                        for g in getattr(self.grants_of(proc), action))
        return ok

    def check(self, proc: str, action: str, key_expr: str) -> None:
        """Raise :class:`AccessDenied` naming the process, the action and the key, with
        what the process may use instead."""
        if not self.allows(proc, action, key_expr):
            allowed = ", ".join(getattr(self.grants_of(proc), action))
            verb = _VERBS[action]
            raise AccessDenied(f"{proc} may not {verb} {key_expr!r} in secure mode; "
                               f"{proc} may {verb}: {allowed} (docs/reference/security.md)")
