"""Controller registry: scenario ``controller.type`` -> :class:`~copath.control.ControllerFactory`.

``controller.type`` is resolved in this order:

1. a built-in name (:data:`CONTROLLERS`), imported lazily so a robot process loads only its
   own controller (and CasADi only when an MPC controller is used);
2. a name that an installed package registers in the entry-point group
   ``copath.controllers`` (``[project.entry-points."copath.controllers"]
   my_law = "my_pkg.law:build"`` in its ``pyproject.toml``);
3. an import path ``package.module:builder``. The module is looked up on ``sys.path``,
   which the orchestrator extends with the scenario file's directory and the directory
   ``copath run`` was started from, for its own process and every child it spawns.

See ``docs/reference/controllers.md`` for the contract.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
from typing import TYPE_CHECKING, Iterable

from copath.config import ConfigError
from copath.control import Controller, ControllerFactory, RobotContext, as_factory

if TYPE_CHECKING:
    from copath.scenario import Scenario

__all__ = ["CONTROLLERS", "ENTRY_POINT_GROUP", "build_controller", "resolve_controller", "registered_names",
           "extend_import_path", "import_path_dirs", "team_factories", "task_queues"]

ENTRY_POINT_GROUP = "copath.controllers"

CONTROLLERS: dict[str, str] = {
    # Sec. 5.5: Lyapunov path following + second-order consensus (unicycles)
    "consensus": "agent.controllers.consensus:build",
    # Sec. 4.2: omni NMPC path following / trajectory tracking
    "omni_nmpc_pf": "agent.controllers.omni_nmpc:build_path_following",
    "omni_nmpc_tt": "agent.controllers.omni_nmpc:build_trajectory_tracking",
    # Sec. 4.3: LTV-MPC QP with a velocity profile
    "ltv_mpc": "agent.controllers.ltv_mpc:build",
    # Sec. 4.4: unicycle NMPC blending path following and trajectory tracking
    "unicycle_nmpc": "agent.controllers.unicycle_nmpc:build",
    # Sec. 5.3: leader-following NMPC
    "leader_nmpc": "agent.controllers.leader_following:build_leader",
    "follower_nmpc": "agent.controllers.leader_following:build_follower",
    # Sec. 5.4: distributed MPC (with morphing for several paths)
    "dmpc": "agent.controllers.dmpc:build",
    # Sec. 5.5.5: heterogeneous team
    "hetero_leader": "agent.controllers.heterogeneous:build_leader",
    "hetero_follower": "agent.controllers.heterogeneous:build_follower",
    # Ch. 6: role assignment and formation switching; E6.6 switching on a path
    "roles": "agent.controllers.roles:build",
    "formation_switching": "agent.controllers.formation_switching:build",
}
"""Built-in name -> its family's factory (``agent/controllers/<family>/__init__.py``). A
family's package declares its factories and loads nothing heavy: its law (and CasADi) is
imported when a robot builds it, so resolving a name to learn a family's declarations
(geometry, payloads, done rule) stays light. Only the families a process resolves are
loaded: a robot's own, the scenario's in the orchestrator and the metrics; each registers
its payload schemas with the wire as it loads."""


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def registered_names() -> list[str]:
    """Built-in names and the names installed packages register, sorted."""
    return sorted(set(CONTROLLERS) | set(_entry_points()))


_IMPORT_DIRS: list[str] = []
"""Directories added for import-path controllers, in the order they were added."""


def extend_import_path(dirs: Iterable[str]) -> None:
    """Put ``dirs`` at the front of ``sys.path`` (once each) for import-path controllers;
    :func:`import_path_dirs` returns them for the processes the orchestrator spawns."""
    for d in reversed([str(d) for d in dirs if d]):
        if d not in sys.path:
            sys.path.insert(0, d)
        if d not in _IMPORT_DIRS:
            _IMPORT_DIRS.append(d)


def import_path_dirs() -> tuple[str, ...]:
    """The directories :func:`extend_import_path` added (for a child's ``PYTHONPATH``)."""
    return tuple(_IMPORT_DIRS)


def _import(target: str, kind: str, key: str) -> object:
    module, _, attr = target.partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module == exc.name or module.startswith(exc.name + ".")):
            raise ConfigError(f"{key} = {kind!r} is not allowed; no module named {exc.name!r}: an import path "
                              "must be 'package.module:builder' importable from the scenario's directory, the "
                              "current directory or an installed package") from None
        raise ConfigError(f"{key} = {kind!r} is not allowed; importing module {module!r} failed: {exc}") from None
    except Exception as exc:  # the module exists but raises while importing: say where
        raise ConfigError(f"{key} = {kind!r} is not allowed; importing module {module!r} failed: "
                          f"{type(exc).__name__}: {exc}") from None
    try:
        return getattr(mod, attr)
    except AttributeError:
        raise ConfigError(f"{key} = {kind!r} is not allowed; module {module!r} has no attribute "
                          f"{attr!r}") from None


def resolve_controller(kind: str, key: str = "controller.type") -> ControllerFactory:
    """The factory that ``controller.type = kind`` names (raises ConfigError naming ``key`` if none)."""
    if kind in CONTROLLERS:
        return as_factory(_import(CONTROLLERS[kind], kind, key), kind)
    eps = _entry_points()
    if kind in eps:
        try:
            obj = eps[kind].load()
        except Exception as exc:  # a broken plug-in must not hide behind a traceback
            raise ConfigError(f"{key} = {kind!r} is not allowed; its entry point "
                              f"{eps[kind].value!r} failed to load: {type(exc).__name__}: {exc}") from None
        return as_factory(obj, kind)
    if ":" in kind:
        return as_factory(_import(kind, kind, key), kind)
    raise ConfigError(f"{key} = {kind!r} is not allowed; registered: {', '.join(registered_names())}, "
                      "or an import path 'package.module:builder'")


def build_controller(kind: str, ctx: RobotContext) -> Controller:
    """Build the controller that ``kind`` names for robot ``ctx``."""
    return resolve_controller(kind)(ctx)


def team_factories(scenario: "Scenario") -> dict[str, ControllerFactory | None]:
    """{robot: the factory its ``controller.type`` names} in the scenario's robot order, None
    for a name that does not resolve (validation reports it; a finished run is still graded):
    what the metrics ask for a family's declarations instead of comparing names."""
    out: dict[str, ControllerFactory | None] = {}
    by_kind: dict[str, ControllerFactory | None] = {}
    for r in scenario.robots:
        if r.controller not in by_kind:
            try:
                by_kind[r.controller] = resolve_controller(r.controller, f"robots.{r.name}.controller.type")
            except ConfigError:
                by_kind[r.controller] = None
        out[r.name] = by_kind[r.controller]
    return out


def task_queues(scenario: "Scenario") -> dict:
    """{robot: its :class:`copath.occupancy.TaskQueue`} of the robots whose family declares a
    done rule (:attr:`~copath.control.ControllerFactory.tasks`), in the scenario's robot order."""
    factories = team_factories(scenario)
    out = {}
    for r in scenario.robots:
        factory = factories[r.name]
        if factory is not None and factory.tasks is not None:
            queue = factory.tasks(r.params)
            if queue is not None:
                out[r.name] = queue
    return out
