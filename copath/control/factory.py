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

from dataclasses import dataclass
from typing import Any, Callable

from ..config import ConfigError, from_table
from .contract import Controller, RobotContext

__all__ = ["ControllerFactory", "controller", "as_factory"]


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
               check: Callable[[RobotContext, Any], None] | None = None
               ) -> Callable[[Callable[[RobotContext, Any], Controller]], ControllerFactory]:
    """Decorator that turns ``build(ctx, cfg)`` into a :class:`ControllerFactory`."""

    def wrap(fn: Callable[[RobotContext, Any], Controller]) -> ControllerFactory:
        return ControllerFactory(fn, config, needs_path, tuple(models) if models else None, check,
                                 getattr(fn, "__qualname__", ""))

    return wrap


def as_factory(obj: Any, name: str, key: str = "controller.type") -> ControllerFactory:
    """A :class:`ControllerFactory` for ``obj``: a factory, or a plain ``build(ctx)``."""
    if isinstance(obj, ControllerFactory):
        return ControllerFactory(obj.build, obj.config, obj.needs_path, obj.models, obj.check, name)
    if callable(obj):
        return ControllerFactory(lambda ctx, _params: obj(ctx), None, False, None, None, name)
    raise ConfigError(f"{key} = {name!r} is not allowed; it names {type(obj).__name__}, "
                      "expected a controller builder (a function build(ctx) or a @controller factory)")
