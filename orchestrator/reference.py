"""The reference tables of the docs, generated from the code so that they cannot drift.

``python -m orchestrator.reference`` rewrites the generated blocks of docs/reference/scenarios.md,
docs/reference/controller-parameters.md and docs/reference/controllers.md (the ``Path`` API) from the
scenario's config dataclasses (their attribute docstrings, types and defaults), the path
constructors, the target table and the controller registry; ``--figures`` also draws
docs/img/path-<type>.png, one small figure per path type. ``--check`` exits 1 when a
committed page differs from what the code generates (tests/unit/test_reference_docs.py
runs the same comparison).

A generated block sits between ``<!-- generated: NAME -->`` and ``<!-- end generated -->``;
the prose around it is written by hand.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import inspect
import math
import pathlib
import re
import sys
import textwrap
import types
import typing
from typing import Any, Callable

__all__ = ["field_docs", "fields_of", "FieldInfo", "type_name", "default_text", "render", "BLOCKS", "PAGES",
           "main", "path_figure_examples"]

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs"


# --------------------------------------------------------------------- dataclass fields
def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings of a (data)class and its bases: the string literal right after
    each annotated attribute (the convention of every config dataclass here)."""
    out: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object:
            continue
        try:
            src = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        tree = ast.parse(src)
        node = next((n for n in tree.body if isinstance(n, ast.ClassDef)), None)
        if node is None:
            continue
        body = node.body
        for a, b in zip(body, body[1:]):
            if (isinstance(a, ast.AnnAssign) and isinstance(a.target, ast.Name) and isinstance(b, ast.Expr)
                    and isinstance(b.value, ast.Constant) and isinstance(b.value.value, str)):
                out[a.target.id] = inspect.cleandoc(b.value.value)
    return out


@dataclasses.dataclass(frozen=True)
class FieldInfo:
    """One key of a scenario table."""

    name: str
    type: str
    """Its type in TOML words (``number``, ``integer``, ``true/false``, ``string``, ...)."""
    default: str
    """Its default as a TOML literal, or ``required``."""
    doc: str
    """Its attribute docstring, on one line."""


def _plural(name: str) -> str:
    return name + "s" if name in ("number", "integer", "string", "table") else name


def type_name(tp: Any) -> str:
    """A type annotation in TOML words."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is float:
        return "number"
    if tp is int:
        return "integer"
    if tp is bool:
        return "true/false"
    if tp is str:
        return "string"
    if tp is type(None):
        return "none"
    if origin is typing.Literal:
        return " or ".join(f'"{a}"' if isinstance(a, str) else repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        parts = [type_name(a) for a in args if a is not type(None)]
        return " or ".join(parts) + (" (optional)" if type(None) in args else "")
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_plural(type_name(args[0]))}"
        if args and all(a == args[0] for a in args):
            return f"list of {len(args)} {type_name(args[0])}s"
        return "list"
    if origin in (list, typing.List):
        return f"list of {_plural(type_name(args[0]))}" if args else "list"
    if origin in (dict, typing.Dict, typing.Mapping) or tp in (dict, typing.Mapping) or (
            origin is not None and getattr(origin, "__name__", "") == "Mapping"):
        if len(args) == 2 and args[1] is not typing.Any:
            return f"table of {type_name(args[1])}"
        return "table"
    if dataclasses.is_dataclass(tp):
        return "table"
    if tp is typing.Any:
        return "any"
    return getattr(tp, "__name__", str(tp))


def _literal(v: Any) -> str:
    if v is None:
        return "(none)"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_literal(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_literal(x)}" for k, x in v.items()) + "}" if v else "{}"
    if dataclasses.is_dataclass(v):
        return "(table)"
    return repr(v)


def default_text(f: dataclasses.Field) -> str:
    """A field's default as a TOML literal; ``required`` when it has none."""
    if f.default is not dataclasses.MISSING:
        return _literal(f.default)
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return _literal(f.default_factory())  # type: ignore[misc]
    return "required"


def fields_of(cls: type, skip: tuple[str, ...] = ()) -> list[FieldInfo]:
    """The keys of config dataclass ``cls`` (init fields), in declaration order."""
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    return [FieldInfo(f.name, type_name(hints.get(f.name, Any)), default_text(f), _md(" ".join(docs.get(f.name, "").split())))
            for f in dataclasses.fields(cls) if f.init and f.name not in skip]


_ROLE_RE = re.compile(r":(?:func|mod|class|meth|data|attr):`~?([^`]+)`")


def _md(text: str) -> str:
    """A docstring's reST roles and double back-quotes as markdown code."""
    return _ROLE_RE.sub(r"`\1`", text).replace("``", "`")


def _cell(text: str) -> str:
    return _md(text).replace("|", "\\|").replace("\n", " ")


def _table(rows: list[FieldInfo], prefix: str = "") -> str:
    lines = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| `{prefix}{r.name}` | {r.type} | `{_cell(r.default)}` | {_cell(r.doc) or '-'} |")
    return "\n".join(lines)


# --------------------------------------------------------------------- the blocks
def _run() -> str:
    from copath.scenario import Kill, RunConfig

    return "\n\n".join([_table(fields_of(RunConfig)),
                        "Each entry of `kills` (a list of tables):\n\n" + _table(fields_of(Kill))])


def _network() -> str:
    from copath.scenario import NetworkConfig, Partition, Silence

    return "\n\n".join([
        _table(fields_of(NetworkConfig)),
        "Each entry of `partitions` (a list of tables):\n\n" + _table(fields_of(Partition)),
        "Each entry of `silence` (a list of tables):\n\n" + _table(fields_of(Silence)),
    ])


def _noise() -> str:
    from copath.scenario import NoiseConfig

    return _table(fields_of(NoiseConfig))


def _sensors() -> str:
    from copath.scenario import SensorConfig

    return _table(fields_of(SensorConfig))


def _sensing() -> str:
    from copath.estimation import BUILTIN_PROFILES, EstimatorConfig, SensorProfile, _SensingTable

    profiles = ", ".join(f"`{p}`" for p in ["realistic", *BUILTIN_PROFILES])
    return "\n\n".join([
        _table(fields_of(_SensingTable)),
        "| key | type | default | meaning |\n|---|---|---|---|\n"
        "| `robots` | table of string | `{}` | per-robot profile, e.g. `{ r2 = \"ideal\" }` |",
        "Estimator tuning, also flat keys of `[sensing]`:\n\n" + _table(fields_of(EstimatorConfig)),
        f"Each `[sensing.profiles.NAME]` (built-in profiles: {profiles}; `realistic` is "
        "`realistic-omni` or `realistic-unicycle` by the robot's model) takes `base` (a built-in "
        "profile to start from, default `\"ideal\"`) and these keys:\n\n" + _table(fields_of(SensorProfile)),
    ])


def path_figure_examples() -> dict[str, dict[str, Any]]:
    """One example table per path type (the figures of docs/reference/scenarios.md draw these)."""
    from copath.paths import PATH_TYPES

    ex = {
        "eight": {"type": "eight"},
        "lemniscate": {"type": "lemniscate"},
        "ellipse": {"type": "ellipse", "a": 1.5, "b": 1.0},
        "circle": {"type": "circle", "radius": 1.0},
        "sinusoid": {"type": "sinusoid", "amplitude": 0.5, "wavelength": 3.0, "length": 6.0},
        "line": {"type": "line", "start": [0.0, 0.0], "heading": 0.5, "length": 4.0},
        "spline": {"type": "spline", "waypoints": [[0, 0], [1.5, 1.0], [3.0, 0.0], [4.5, 1.0]]},
    }
    missing = set(PATH_TYPES) - set(ex)
    if missing:
        raise KeyError(f"no example for path types {sorted(missing)}: add one to path_figure_examples()")
    return ex


def _paths() -> str:
    from copath.paths import PATH_TYPES

    examples = path_figure_examples()
    out = []
    for kind, fn in PATH_TYPES.items():
        sig = inspect.signature(fn)
        keys = []
        for p in sig.parameters.values():
            default = "required" if p.default is inspect.Parameter.empty else _literal(p.default)
            keys.append(f"`{p.name}` ({default})")
        doc = " ".join(inspect.getdoc(fn).split("\n\n")[0].split())
        ex = ", ".join(f"{k} = {_literal(v)}" for k, v in examples[kind].items())
        out.append(f"**`{kind}`**: {_md(doc)}\n\n- keys: {', '.join(keys)}\n- figure: `{{ {ex} }}`\n\n"
                   f"![path type {kind}](../img/path-{kind}.png)")
    return "\n\n".join(out)


def _models() -> str:
    from copath.models import MODEL_TYPES

    return "\n\n".join(f"`model = \"{kind}\"` or `model = {{ type = \"{kind}\", ... }}` with:\n\n"
                       + _table(fields_of(cls)) for kind, cls in MODEL_TYPES.items())


def _world() -> str:
    from copath.ros2.config import RobotIO, WorldConfig

    world = fields_of(WorldConfig)
    world.insert(2, FieldInfo("pose_type", "string", '"odometry"', "Default pose source of every robot: "
                              "`odometry` (nav_msgs/Odometry) or `pose_stamped` (geometry_msgs/PoseStamped)."))
    defaults = {"pose_topic": "/<robot>/odom (odometry) or /<robot>/pose (pose_stamped)",
                "pose_type": "[world] pose_type", "cmd_topic": "/<robot>/cmd_vel",
                "origin": '"start" (odometry), [0.0, 0.0, 0.0] (pose_stamped)'}
    io = [dataclasses.replace(f, default=defaults.get(f.name, f.default)) for f in fields_of(RobotIO)]
    return _table(world) + "\n\nEach `[world.robots.NAME]` (every key optional):\n\n" + _table(io)


def _obstacles() -> str:
    from copath.scenario import ObstacleSpec

    return _table(fields_of(ObstacleSpec))


def _metrics_table() -> str:
    from copath.metrics_config import MetricsConfig

    return _table(fields_of(MetricsConfig))


def _safety() -> str:
    from copath.safety import SafetyConfig

    return _table(fields_of(SafetyConfig))


def _targets() -> str:
    from copath.grading import AT_MOST, TARGETS

    lines = ["| key | graded on | direction | passes when |", "|---|---|---|---|"]
    for key, (scope, sense) in TARGETS.items():
        who = "the worst robot" if scope == "robots" else "the fleet"
        direction = "maximum (upper bound)" if sense == AT_MOST else "minimum (lower bound)"
        lines.append(f"| `{key}` | {who} | {direction} | value {sense} threshold |")
    return "\n".join(lines)


def _controllers() -> str:
    from agent.controllers import CONTROLLERS, resolve_controller

    out = []
    for name in sorted(CONTROLLERS):
        f = resolve_controller(name)
        needs = [f"models: {', '.join(f.models)}" if f.models else "any model"]
        if f.needs_path:
            needs.append("needs a path")
        head = f"### `{name}`\n\n{'; '.join(needs)}. Parameters: `{f.config.__module__}.{f.config.__qualname__}`"
        doc = inspect.getdoc(f.config) or ""
        first = " ".join(doc.split("\n\n")[0].split()) if doc and not doc.startswith(f.config.__name__ + "(") else ""
        out.append(head + (f"\n\n{_md(first)}" if first else "") + "\n\n" + _table(fields_of(f.config)))
    return "\n\n".join(out)


def _public(cls: type) -> list[tuple[str, str, str]]:
    """(name, signature, first paragraph of its docstring) of each public member of cls."""
    out = []
    for name, member in cls.__dict__.items():
        if name.startswith("_"):
            continue
        if isinstance(member, property):
            sig, doc = "", inspect.getdoc(member) or ""
        elif callable(member):
            try:
                params = list(inspect.signature(member).parameters.values())[1:]
                sig = "(" + ", ".join(p.name if p.default is inspect.Parameter.empty else f"{p.name}={p.default!r}"
                                      for p in params) + ")"
            except (TypeError, ValueError):
                sig = "(...)"
            doc = inspect.getdoc(member) or ""
        else:
            continue
        out.append((name, sig, " ".join(doc.split("\n\n")[0].split())))
    return out


_PATH_ATTRS = {
    "name": "the path type's name (`\"ellipse\"`, ...)",
    "length": "arc length L of the path [m] (one lap of a closed path)",
    "closed": "True for a closed curve (s wraps modulo `length`), False for an open one",
    "winding": "turns of the tangent per lap of a closed path (0 for open paths)",
}
"""Public attributes set in ``Path.__init__`` (they have no docstring of their own)."""


def _path_api() -> str:
    from copath.paths import Path, PathTable

    lines = ["| member | what it gives |", "|---|---|"]
    for name, doc in _PATH_ATTRS.items():
        lines.append(f"| `Path.{name}` | {_cell(doc)} |")
    for name, sig, doc in _public(Path):
        lines.append(f"| `Path.{name}{_cell(sig)}` | {_cell(doc)} |")
    lines += ["", "`PathTable` (from `Path.table(step)`; the same geometry, tabulated for speed):", "",
              "| member | what it gives |", "|---|---|"]
    lines.append("| `PathTable.grid` | (n,) arc lengths of the samples [m] (uniform) |")
    for name, sig, doc in _public(PathTable):
        shown = "__call__" if name == "__call__" else name
        lines.append(f"| `PathTable.{shown}{_cell(sig)}` | {_cell(doc)} |")
    call = inspect.getdoc(PathTable.__call__) or ""
    lines.append(f"| `PathTable(s)` (call) | {_cell(' '.join(call.split()))} |")
    return "\n".join(lines)


BLOCKS: dict[str, Callable[[], str]] = {
    "run": _run,
    "network": _network,
    "noise": _noise,
    "sensors": _sensors,
    "sensing": _sensing,
    "paths": _paths,
    "models": _models,
    "obstacles": _obstacles,
    "world": _world,
    "metrics": _metrics_table,
    "safety": _safety,
    "targets": _targets,
    "controllers": _controllers,
    "path-api": _path_api,
}
"""Generated block name -> the function that writes its markdown."""

PAGES = ("reference/scenarios.md", "reference/controller-parameters.md", "reference/controllers.md")
"""The docs pages (under docs/) that hold generated blocks."""

_BLOCK_RE = re.compile(r"(<!-- generated: ([\w-]+) -->\n)(.*?)(<!-- end generated -->)", re.S)


def render(text: str) -> str:
    """``text`` with every generated block rewritten from the code."""

    def sub(m: re.Match) -> str:
        name = m.group(2)
        if name not in BLOCKS:
            raise KeyError(f"generated block {name!r} is unknown; known: {', '.join(BLOCKS)}")
        return f"{m.group(1)}{BLOCKS[name]().rstrip()}\n{m.group(4)}"

    return _BLOCK_RE.sub(sub, text)


def blocks_in(text: str) -> list[str]:
    """Names of the generated blocks of a page."""
    return [m.group(2) for m in _BLOCK_RE.finditer(text)]


# --------------------------------------------------------------------- figures
def draw_path_figures(out_dir: pathlib.Path) -> list[pathlib.Path]:
    """docs/img/path-<type>.png: each example path, its start (s = 0) and direction."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from copath.paths import make_path

    files = []
    for kind, spec in path_figure_examples().items():
        path = make_path(dict(spec))
        s = np.linspace(0.0, path.length, 400)
        p = path.pos(s)
        fig, ax = plt.subplots(figsize=(3.2, 2.4))
        ax.plot(p[:, 0], p[:, 1], color="C0", lw=1.5)
        x, y, th, _ = path.frame(0.0)
        ax.plot([x], [y], "o", color="C3", ms=4)
        ax.annotate("", xy=(x + 0.4 * math.cos(th), y + 0.4 * math.sin(th)), xytext=(x, y),
                    arrowprops={"arrowstyle": "->", "color": "C3"})
        ax.set_aspect("equal")
        ax.grid(True, lw=0.3)
        ax.tick_params(labelsize=7)
        ax.set_title(f"{kind}: L = {path.length:.2f} m ({'closed' if path.closed else 'open'})", fontsize=8)
        fig.tight_layout()
        f = out_dir / f"path-{kind}.png"
        fig.savefig(f, dpi=80, metadata={"Software": None})
        plt.close(fig)
        files.append(f)
    return files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m orchestrator.reference", description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when a committed page differs; write nothing")
    ap.add_argument("--figures", action="store_true", help="also draw docs/img/path-<type>.png")
    ap.add_argument("--docs", default=str(DOCS), help="the docs directory [the repository's docs/]")
    args = ap.parse_args(argv)
    docs = pathlib.Path(args.docs)
    stale = []
    for page in PAGES:
        f = docs / page
        text = f.read_text()
        new = render(text)
        if new != text:
            stale.append(page)
            if not args.check:
                f.write_text(new)
    if args.check:
        for page in stale:
            print(f"docs/{page} is out of date: run python -m orchestrator.reference", file=sys.stderr)
        return 1 if stale else 0
    for page in stale:
        print(f"wrote docs/{page}")
    if args.figures:
        for f in draw_path_figures(docs / "img"):
            print(f"wrote {f.relative_to(docs.parent)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
