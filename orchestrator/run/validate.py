"""Validate a whole scenario before any process starts (``copath validate``, step one of ``copath run``).

Two layers, each reporting *every* problem it finds as ``key = value is not allowed; rule``:

1. the scenario itself (:func:`copath.scenario.parse_scenario`): tables, keys, types,
   ranges, and the cross-field rules (settle before the end of the run, positive curve
   sizes, start poses at least two radii apart, partition links on graph edges);
2. each robot's controller (:mod:`agent.controllers`): the type resolves (a registered
   name, an entry point or an import path), the robot has a path if the controller needs
   one and a model it can drive, and the ``[controller]`` parameters parse into the
   controller's declared dataclass (a typo such as ``k_one`` is named with the allowed keys).

Nothing here builds a solver: checking a 16-robot MPC scenario takes milliseconds.
"""

from __future__ import annotations

import os
import pathlib
import re
from typing import Any, Mapping

from agent.controllers import extend_import_path, resolve_controller, task_queues
from copath.config import ConfigError, ConfigErrors
from copath.control import RobotContext
from copath.scenario import Scenario, load_scenario, parse_scenario

__all__ = ["controller_errors", "validate_scenario", "validate_table", "validate_file", "import_dirs",
           "use_import_dirs"]


def import_dirs(scenario_dir: str | os.PathLike | None) -> list[str]:
    """Directories searched for import-path controllers: the scenario's, then the current one."""
    dirs = [str(pathlib.Path(scenario_dir).resolve())] if scenario_dir else []
    dirs.append(os.getcwd())
    return list(dict.fromkeys(dirs))


def use_import_dirs(dirs: list[str]) -> None:
    """Make ``dirs`` importable here, and (through :func:`agent.controllers.import_path_dirs`,
    which the orchestrator puts on each child's ``PYTHONPATH``) in every process it spawns,
    so ``package.module:builder`` resolves alike in all. ``os.environ`` is left alone."""
    extend_import_path(dirs)


def _shared(msg: str, robot: str, shared: Mapping[str, Any], own: Mapping[str, Any]) -> str:
    """A robot's controller problem about a key it takes from the shared ``[controller]``
    table, named as that table's key (``controller.k_one = ...``), so that it is reported
    once for the table rather than once per robot."""
    m = re.match(rf"robots\.{re.escape(robot)}\.controller(?:\.|: )(\w+)( = .*)$", msg, re.S)
    if m and m.group(1) in shared and m.group(1) not in own:
        return f"controller.{m.group(1)}{m.group(2)}"
    return msg


def _own_table(scenario: Scenario, robot: str) -> Mapping[str, Any]:
    for r in scenario.raw.get("robots") or []:
        if isinstance(r, dict) and r.get("name") == robot:
            return r.get("controller") or {}
    return {}


def controller_errors(scenario: Scenario) -> list[str]:
    """Every controller problem of ``scenario`` (empty when all robots are fine), each once:
    a problem of a shared ``[controller]`` key is named as that key, not per robot."""
    errors: list[str] = []
    if scenario.world.ros2:  # a ROS 2 world without ROS 2 installed: one line saying what to install
        from copath.ros2 import missing

        errors.extend([m] if (m := missing()) else [])
    resolved: dict[str, Any] = {}
    shared = scenario.raw.get("controller") or {}
    offsets = (scenario.metrics or {}).get("path_offsets") or {}
    for spec in scenario.robots:
        if spec.path is not None and spec.path not in scenario.paths:
            continue  # its path table did not build; that error is reported already
        if spec.controller not in resolved:
            try:
                resolved[spec.controller] = resolve_controller(spec.controller, f"robots.{spec.name}.controller.type")
            except ConfigError as exc:
                resolved[spec.controller] = None
                errors.append(_shared(str(exc), spec.name, shared, _own_table(scenario, spec.name)))
        factory = resolved[spec.controller]
        if factory is not None:
            ctx = RobotContext.for_robot(scenario, spec.name)
            own = _own_table(scenario, spec.name)
            found = [_shared(e, spec.name, shared, own) for e in factory.validate(ctx)]
            errors.extend(found)
            if not found and spec.name in offsets:
                errors.extend(_offset_errors(factory, ctx, offsets[spec.name]))
    if scenario.run.until == "tasks_done" and not task_queues(scenario):
        errors.append("run.until = 'tasks_done' is not allowed; 'tasks_done' needs robots with a task queue "
                      "(a controller family that declares a done rule, as 'roles' does)")
    return list(dict.fromkeys(errors))


def _offset_errors(factory: Any, ctx: RobotContext, declared: float) -> list[str]:
    """The robot's along-path offset ``s_d`` (its controller's parameter, default included)
    against ``[metrics] path_offsets``: the two must say the same (docs/reference/scenarios.md)."""
    try:
        cfg = factory.parse(ctx)
    except ConfigError:
        return []
    s_d = cfg.get("s_d") if isinstance(cfg, dict) else getattr(cfg, "s_d", None)
    if isinstance(s_d, bool) or not isinstance(s_d, (int, float)) or abs(float(s_d) - float(declared)) <= 1e-9:
        return []
    given = "given" if "s_d" in ctx.params else "its controller's default"
    return [f"robots.{ctx.name}.controller.s_d = {s_d!r} is not allowed; metrics.path_offsets.{ctx.name} = "
            f"{declared!r} says otherwise for robot {ctx.name} (s_d {given}): the controller's offset and the "
            "scored one must agree"]


def validate_scenario(scenario: Scenario) -> Scenario:
    """Raise :class:`ConfigErrors` listing every controller problem of a parsed scenario."""
    errors = controller_errors(scenario)
    if errors:
        raise ConfigErrors(errors)
    return scenario


def validate_table(raw: Mapping[str, Any], base_dir: pathlib.Path | None = None, source: str = "") -> Scenario:
    """Parse and fully validate a scenario table (both layers)."""
    use_import_dirs(import_dirs(base_dir))
    return parse_scenario(raw, base_dir=base_dir, source=source, checks=controller_errors)


def validate_file(path: str | os.PathLike) -> Scenario:
    """Load and fully validate a scenario file (both layers)."""
    use_import_dirs(import_dirs(pathlib.Path(path).parent))
    return load_scenario(path, checks=controller_errors)
