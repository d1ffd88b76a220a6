"""Helpers that turn scenario tables into validated frozen dataclasses.

Every component's config is a frozen dataclass (docstring per attribute) validated in
``__post_init__``; :func:`from_table` builds one from a TOML table and names the key,
the value and what is allowed when the table is wrong.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, Mapping, TypeVar

__all__ = ["ConfigError", "ConfigErrors", "from_table", "require", "as_float_tuple"]

T = TypeVar("T")


class ConfigError(ValueError):
    """A scenario or CLI value is not allowed; the message names key, value and rule."""


class ConfigErrors(ConfigError):
    """Several problems at once (``copath validate`` prints them all); ``errors`` lists
    one-line messages, and ``str()`` joins them with newlines."""

    def __init__(self, errors: list[str]) -> None:
        self.errors = list(errors)
        super().__init__("\n".join(self.errors))


def require(cond: bool, key: str, value: Any, allowed: str) -> None:
    """Raise :class:`ConfigError` ``"<key> = <value> is not allowed; <allowed>"`` unless cond."""
    if not cond:
        raise ConfigError(f"{key} = {value!r} is not allowed; {allowed}")


def as_float_tuple(value: Any, key: str, length: int | None = None) -> tuple[float, ...]:
    """Convert a scalar or list to a tuple of floats, checking the length."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = [value] * (length or 1)
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key} = {value!r} is not allowed; expected a list of numbers") from None
    if length is not None and len(out) != length:
        raise ConfigError(f"{key} = {value!r} is not allowed; expected {length} numbers")
    return out


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key} = {value!r} is not allowed; expected a number")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{key} = {value!r} is not allowed; expected an integer")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key} = {value!r} is not allowed; expected true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key} = {value!r} is not allowed; expected a string")
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, (list, tuple)):
            value = [value]
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{key} = {value!r} is not allowed; expected {len(args)} values")
        return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        errors = []
        for a in args:
            try:
                return _coerce(value, a, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0])
    return value


def from_table(cls: type[T], table: Mapping[str, Any] | None, where: str) -> T:
    """Build dataclass ``cls`` from ``table``; unknown keys and wrong types raise ConfigError.

    ``where`` is the dotted location of the table in the scenario (e.g. ``robots.r1.controller``)
    and prefixes every message.
    """
    table = dict(table or {})
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    hints = typing.get_type_hints(cls)
    for key, value in table.items():
        if key not in fields:
            raise ConfigError(
                f"{where}.{key} = {value!r} is not allowed; allowed keys: {', '.join(sorted(fields))}"
            )
    kwargs = {k: _coerce(v, hints.get(k, Any), f"{where}.{k}") for k, v in table.items()}
    try:
        return cls(**kwargs)
    except ConfigErrors:
        raise
    except ConfigError as exc:  # a __post_init__ that names its own key bare ("v0 = ..."): say where
        msg = str(exc)
        if msg.split(" = ", 1)[0] in fields:
            raise ConfigError(f"{where}.{msg}") from None
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc
