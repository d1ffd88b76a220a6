"""How a controller declares itself: its builder, its parameter dataclass, what it needs.

A controller type is a :class:`ControllerFactory`. It is what ``controller.type`` in a
scenario names (a registered name, an entry point of the group ``copath.controllers``, or
an import path ``package.module:builder``), and it lets the orchestrator check a
scenario's controller parameters *before any process starts* (``copath validate``):
parameters are parsed into the declared frozen dataclass with
:func:`copath.config.from_table`, so a typo such as ``k_one = 5.0`` is reported with its
key path, its value and the allowed keys.

Declare one with the :func:`controller` decorator::

    from dataclasses import dataclass
    from copath.control import RobotContext, controller

    @dataclass(frozen=True)
    class PursuitConfig:
        lookahead_m: float = 0.4
        \"\"\"Look-ahead distance along the path [m].\"\"\"

    @controller(config=PursuitConfig, needs_path=True, models=("unicycle",))
    def build(ctx: RobotContext, cfg: PursuitConfig) -> "PurePursuit":
        return PurePursuit(ctx, cfg)

A plain function ``build(ctx) -> Controller`` is accepted too (see :func:`as_factory`);
its parameters are then passed through unchecked.
"""

from __future__ import annotations

import dataclasses
import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

from ..config import ConfigError, from_table
from ..wire.payloads import register_payloads
from .contract import Controller, RobotContext

if TYPE_CHECKING:  # type names only: declaring a factory stays light
    from ..occupancy import TaskQueue
    from ..scenario import Scenario
    from ..team import TeamGeometry

__all__ = ["ControllerFactory", "controller", "as_factory", "deferred"]


@dataclass(frozen=True)
class deferred:  # noqa: N801 (used like a function: geometry=deferred("pkg.mod:fn"))
    """A declaration that imports its function when first called: ``deferred("pkg.mod:fn")(*a)``
    is ``pkg.mod.fn(*a)``. A family declares its team geometry this way, so that a robot,
    which resolves its factory to build its law, never loads the grading code, and the
    metrics, which grade, never load the law. Two with the same target are equal (a team
    whose robots declare the same geometry)."""

    target: str
    """``package.module:function``."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        module, _, attr = self.target.partition(":")
        return getattr(importlib.import_module(module), attr)(*args, **kwargs)


@dataclass(frozen=True)
class ControllerFactory:
    """A controller type: builder plus the declarations used to validate a scenario."""

    build: Callable[[RobotContext, Any], Controller]
    """``build(ctx, cfg)``; ``cfg`` is the parsed :attr:`config` (or the raw params)."""
    config: type | None = None
    """Frozen dataclass of the ``[controller]`` parameters, or None (unchecked)."""
    needs_path: bool = False
    """The robot must have a path (``robots.path``)."""
    models: tuple[str, ...] | None = None
    """Allowed robot model kinds (``"omni"``, ``"unicycle"``); None allows any."""
    check: Callable[[RobotContext, Any], None] | None = None
    """Optional cheap cross-field check ``check(ctx, cfg)`` raising ConfigError."""
    name: str = ""
    """How the scenario named it (filled in by the resolver)."""
    geometry: "Callable[[Scenario], TeamGeometry | None] | None" = None
    """The team's desired geometry for grading from the truth (:class:`copath.team.TeamGeometry`):
    ``geometry(scenario)`` for a team whose robots all declare this same function, or None
    (the team is not one this family grades, e.g. a leader without followers). None here:
    the family declares no geometry (``[metrics] path_offsets`` may still give one)."""
    payloads: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    """Schemas of the message kinds the family sends, ``{kind: {field: type}}`` in the form of
    :mod:`copath.wire.payloads`; declaring the factory registers them with the wire, so
    receivers validate every payload of these kinds against them."""
    tasks: "Callable[[Mapping[str, Any]], TaskQueue | None] | None" = None
    """The family's done rule (Chapter 6 occupancy, :mod:`copath.occupancy`): the robot's task
    queue read from its ``[controller]`` table, or None. Robots with a queue are the ones
    ``run.until = "tasks_done"`` and the task metrics watch."""
    handles_cut_off: bool = False
    """The controller rules on a cut-off robot itself (no hold by the runtime; the roles
    family's cut-off rule, docs/reference/faults.md "Gone quiet")."""
    handles_obstacles: bool = False
    """The controller avoids obstacles itself (the runtime adds no obstacle filter)."""

    def __post_init__(self) -> None:
        if self.payloads:
            register_payloads(self.payloads)

    def parse(self, ctx: RobotContext) -> Any:
        """The robot's parameters as :attr:`config` (raises ConfigError naming the key)."""
        if self.config is None:
            return dict(ctx.params)
        return from_table(self.config, ctx.params, f"robots.{ctx.name}.controller")

    def validate(self, ctx: RobotContext) -> list[str]:
        """Every problem of this robot's controller set-up, as one-line messages."""
        return self._checked(ctx)[0]

    def _checked(self, ctx: RobotContext) -> tuple[list[str], Any]:
        """(problems, parsed config or None): one parse serves the check and the build."""
        errors: list[str] = []
        where = f"robots.{ctx.name}"
        if self.needs_path and ctx.path is None:
            errors.append(f"{where}.path = None is not allowed; controller type {self.name!r} needs a path "
                          "(name a table under [paths])")
        if self.models is not None and ctx.model.kind not in self.models:
            errors.append(f"{where}.model = {ctx.model.kind!r} is not allowed; controller type {self.name!r} "
                          f"drives: {', '.join(self.models)}")
        try:
            cfg = self.parse(ctx)
        except ConfigError as exc:
            errors.append(str(exc))
            return errors, None
        if self.check is not None and not errors:
            try:
                self.check(ctx, cfg)
            except (ConfigError, ValueError) as exc:
                errors.append(str(exc) if isinstance(exc, ConfigError) else f"{where}.controller: {exc}")
        return errors, cfg

    def __call__(self, ctx: RobotContext) -> Controller:
        errors, cfg = self._checked(ctx)
        if errors:
            raise ConfigError("; ".join(errors))
        return self.build(ctx, cfg)


def controller(*, config: type | None = None, needs_path: bool = False, models: tuple[str, ...] | None = None,
               check: Callable[[RobotContext, Any], None] | None = None, **declared: Any
               ) -> Callable[[Callable[[RobotContext, Any], Controller]], ControllerFactory]:
    """Decorator that turns ``build(ctx, cfg)`` into a :class:`ControllerFactory`.

    ``declared`` holds the family's other declarations, by field name: ``geometry``,
    ``payloads``, ``tasks``, ``handles_cut_off``, ``handles_obstacles``."""
    allowed = {f.name for f in dataclasses.fields(ControllerFactory)} - {"build", "config", "needs_path", "models",
                                                                       "check", "name"}
    unknown = sorted(set(declared) - allowed)
    if unknown:
        raise TypeError(f"controller() got unknown declarations {unknown}; allowed: {sorted(allowed)}")

    def wrap(fn: Callable[[RobotContext, Any], Controller]) -> ControllerFactory:
        return ControllerFactory(fn, config, needs_path, tuple(models) if models else None, check,
                                 getattr(fn, "__qualname__", ""), **declared)

    return wrap


def as_factory(obj: Any, name: str, key: str = "controller.type") -> ControllerFactory:
    """A :class:`ControllerFactory` for ``obj``: a factory, or a plain ``build(ctx)``."""
    if isinstance(obj, ControllerFactory):
        return dataclasses.replace(obj, name=name)
    if callable(obj):
        return ControllerFactory(lambda ctx, _params: obj(ctx), None, False, None, None, name)
    raise ConfigError(f"{key} = {name!r} is not allowed; it names {type(obj).__name__}, "
                      "expected a controller builder (a function build(ctx) or a @controller factory)")
