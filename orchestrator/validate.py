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
from typing import Any, Mapping

from agent.controllers import extend_import_path, resolve_controller
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


def controller_errors(scenario: Scenario) -> list[str]:
    """Every controller problem of ``scenario`` (empty when all robots are fine)."""
    errors: list[str] = []
    if scenario.world.ros2:  # a ROS 2 world without ROS 2 installed: one line saying what to install
        from copath.ros2 import missing

        errors.extend([m] if (m := missing()) else [])
    resolved: dict[str, Any] = {}
    for spec in scenario.robots:
        if spec.controller not in resolved:
            try:
                resolved[spec.controller] = resolve_controller(spec.controller, f"robots.{spec.name}.controller.type")
            except ConfigError as exc:
                resolved[spec.controller] = None
                errors.append(str(exc))
        factory = resolved[spec.controller]
        if factory is not None:
            errors.extend(factory.validate(RobotContext.for_robot(scenario, spec.name)))
    return errors


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
