"""A small Python API for notebooks and scripts: find a scenario, change it, run it, read the result.

::

    from orchestrator import api

    s = api.load("e5.5", {"network.loss": 0.1, "run.duration_s": 30})
    run = api.run(s, inprocess=True)          # or api.run(s, out_dir="runs/x") for a real fleet
    run.metrics["fleet"]["coordination_error_max_m"]
    run.grade()                               # the scenario's [targets], pass/fail
    run.poses()["r1"]                         # (n, 4) array: t, x, y, theta (simulator truth)
    run.frame()                               # the same as a pandas DataFrame, where pandas is installed
    api.open_run("runs/x")                    # a recorded run read back from its MCAP log

Scenarios are found by path, by file stem or by the dissertation experiment id among the
bundled scenarios (installed with the package as ``copath_configs``). Overrides use
dotted keys (``network.delay_ms``, ``controller.v0``, ``robots[0].pose`` or
``robots.r1.pose``); values are TOML literals, so the result is validated exactly like
the file.
"""

from __future__ import annotations

import json
import pathlib
import tomllib
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from copath.config import ConfigError, ConfigErrors
from copath.scenario import Scenario, locate_errors, parse_scenario
from copath.grading import TargetResult, figure, grade

__all__ = [
    "Bundled",
    "bundled_dir",
    "bundled_scenarios",
    "find_scenario",
    "parse_value",
    "parse_values",
    "parse_set",
    "apply_overrides",
    "load",
    "Run",
    "run",
    "open_run",
    "HEADLINE",
    "headline",
]

_CHECKOUT_CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"


def bundled_dir() -> pathlib.Path:
    """Directory of the bundled scenarios (the installed ``copath_configs`` package)."""
    try:
        import copath_configs

        return pathlib.Path(copath_configs.__file__).resolve().parent
    except ImportError:  # an editable install made before configs/ became package data
        return _CHECKOUT_CONFIGS


@dataclass(frozen=True)
class Bundled:
    stem: str
    path: pathlib.Path
    experiment: str | None
    title: str


def bundled_scenarios() -> list[Bundled]:
    """Every bundled scenario file, sorted by name (read as TOML, not validated)."""
    out = []
    for f in sorted(bundled_dir().glob("*.toml")):
        try:
            raw = tomllib.loads(f.read_text())
        except tomllib.TOMLDecodeError:
            raw = {}
        out.append(Bundled(f.stem, f, raw.get("experiment"), str(raw.get("title", f.stem))))
    return out


def find_scenario(name: str | pathlib.Path) -> pathlib.Path:
    """The scenario file meant by ``name``: a path, a bundled file stem (or its unique
    prefix), or an experiment id with exactly one bundled scenario."""
    p = pathlib.Path(name)
    if p.is_file():
        return p
    text = str(name)
    if p.suffix in (".toml", ".json") or "/" in text:
        raise ConfigError(f"scenario file {text!r} does not exist")
    known = bundled_scenarios()
    key = text.lower()
    for b in known:
        if b.stem.lower() == key:
            return b.path
    by_exp = [b for b in known if (b.experiment or "").lower() == key]
    by_prefix = [b for b in known if b.stem.lower().startswith(key)]
    hits = by_exp or by_prefix
    if len(hits) == 1:
        return hits[0].path
    if len(hits) > 1:
        raise ConfigError(f"scenario = {text!r} is not allowed; it matches {len(hits)} bundled scenarios, "
                          f"name one by its file stem: {', '.join(b.stem for b in hits)}")
    exps = sorted({b.experiment for b in known if b.experiment})
    raise ConfigError(f"scenario = {text!r} is not allowed; expected a scenario file, a bundled scenario's "
                      f"file stem or an experiment id ({', '.join(exps)}); see `copath scenarios`")


# --- overrides ---

def parse_value(text: str) -> Any:
    """A command-line value as a TOML literal (``0.1``, ``true``, ``[1, 2, 0]``, ``"a"``);
    a bare word that is not TOML is taken as a string (``realtime``)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def parse_values(text: str) -> list[Any]:
    """A comma-separated list of values (sweeps): ``0,0.1,0.2``, ``[0,1],[1,0]``, ``a,b``."""
    try:
        return list(tomllib.loads(f"v = [{text}]")["v"])
    except tomllib.TOMLDecodeError:
        return [parse_value(v) for v in text.split(",")]


def parse_set(item: str) -> tuple[str, str]:
    """Split ``key.path=value``; the key must be non-empty."""
    key, sep, value = item.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"--set {item!r} is not allowed; expected key.path=value, e.g. network.delay_ms=100")
    return key, value.strip()


def _segments(key: str) -> list[str | int]:
    out: list[str | int] = []
    for part in key.split("."):
        name, _, rest = part.partition("[")
        if name:
            out.append(name)
        while rest:
            idx, _, rest = rest.partition("]")
            try:
                out.append(int(idx))
            except ValueError:
                raise ConfigError(f"--set {key} is not allowed; index [{idx}] must be an integer") from None
            rest = rest.lstrip("[")
        if not name and not out:
            raise ConfigError(f"--set {key} is not allowed; empty key")
    return out


def apply_overrides(raw: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of a scenario table with dotted keys set (``robots.r1.pose`` picks the robot named r1)."""
    out = json.loads(json.dumps(raw))  # deep copy of plain TOML data
    for key, value in overrides.items():
        segs = _segments(key)
        node: Any = out
        for i, s in enumerate(segs[:-1]):
            where = ".".join(str(x) for x in segs[: i + 1])
            if isinstance(node, list):
                parent = ".".join(str(x) for x in segs[:i]) or "(top)"
                names = [e.get("name") for e in node if isinstance(e, dict) and "name" in e]
                allowed = (f"expected an entry's name ({', '.join(map(str, names))}) or an index below {len(node)}"
                           if names else f"expected an index below {len(node)}")
                if isinstance(s, str):  # robots.r1 -> the entry whose name is r1
                    named = [e for e in node if isinstance(e, dict) and e.get("name") == s]
                    if not named:
                        raise ConfigError(f"{key} = {value!r} is not allowed; {parent} has no entry {s!r}: {allowed}")
                    node = named[0]
                    continue
                if not -len(node) <= s < len(node):
                    raise ConfigError(f"{key} = {value!r} is not allowed; {parent} has no entry [{s}]: {allowed}")
                node = node[s]
            elif isinstance(node, dict):
                if isinstance(s, int):
                    raise ConfigError(f"{where} is not allowed; [{s}] indexes a table, not a list")
                nxt = node.setdefault(s, {})
                if not isinstance(nxt, (dict, list)):
                    raise ConfigError(f"{key} = {value!r} is not allowed; {where} is a value ({nxt!r}), not a table")
                node = nxt
        last = segs[-1]
        if isinstance(node, list):
            if not isinstance(last, int) or not -len(node) <= last < len(node):
                raise ConfigError(f"{key} = {value!r} is not allowed; expected an index below {len(node)}")
            node[last] = value
        else:
            if isinstance(last, int):
                raise ConfigError(f"{key} = {value!r} is not allowed; [{last}] indexes a table, not a list")
            node[last] = value
    return out


def _as_overrides(overrides: Mapping[str, Any] | Iterable[str] | None) -> dict[str, Any]:
    if overrides is None:
        return {}
    if isinstance(overrides, Mapping):
        return dict(overrides)
    out = {}
    for item in overrides:
        k, v = parse_set(item)
        out[k] = parse_value(v)
    return out


def load(name: str | pathlib.Path | Scenario, overrides: Mapping[str, Any] | Iterable[str] | None = None) -> Scenario:
    """A fully validated scenario (controller parameters included, like ``copath validate``):
    ``name`` is a path, a bundled stem or an experiment id; ``overrides`` maps dotted keys
    to values (or is a list of ``key=value`` strings)."""
    from orchestrator.run.validate import validate_file, validate_table

    ov = _as_overrides(overrides)
    if isinstance(name, Scenario):
        if not ov:
            return name
        return validate_table(apply_overrides(name.raw, ov), base_dir=None, source=name.source)
    path = find_scenario(name)
    if not ov:
        return validate_file(path)
    text = path.read_text()
    if path.suffix == ".json":
        raw = json.loads(text)
        source = str(raw.get("_source", path.name))
    else:
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path.name}: not valid TOML: {exc}") from exc
        source = path.name
    try:
        return validate_table(apply_overrides(raw, ov), base_dir=path.parent, source=source)
    except ConfigErrors as exc:  # the file's line of each key, except the keys --set gave
        if path.suffix == ".json":
            raise
        raise ConfigErrors(locate_errors(exc.errors, text, skip=tuple(ov))) from None


# --- results ---

HEADLINE = ("path_error_max_m", "heading_error_max_rad", "coordination_error_max_m", "formation_error_max_m",
            "min_separation_m", "collisions", "min_obstacle_clearance_m", "tasks_completed", "solve_ms_p99",
            "missed_ticks", "messages_dropped_by_faults")
"""The figures shown for a run at a glance (``copath info``, ``copath sweep``); per-robot
figures are the worst robot's."""


def headline(metrics: Mapping[str, Any], keys: Iterable[str] = HEADLINE) -> dict[str, float | None]:
    """The headline figures of a metrics.json dict (worst robot for per-robot keys)."""
    return {k: figure(metrics, k)[0] for k in keys}


# --- runs ---

@dataclass
class Run:
    """A finished run: metrics (metrics.json) and the decoded message log."""

    scenario: Scenario
    metrics: dict[str, Any]
    records: list[tuple[int, str, Any]] = field(repr=False)
    """(log time [ns], key, decoded record) of every run message."""
    out_dir: pathlib.Path | None = None
    ok: bool = True
    reason: str = "completed"

    @property
    def run_id(self) -> str:
        return str(self.metrics.get("run_id", ""))

    @property
    def log(self) -> pathlib.Path | None:
        return None if self.out_dir is None else self.out_dir / "run.mcap"

    def grade(self) -> list[TargetResult]:
        """The scenario's ``[targets]`` against this run's metrics."""
        return grade(self.scenario.targets, self.metrics)

    @property
    def trace(self):
        """The log as arrays per robot (:class:`orchestrator.analysis.metrics.Trace`)."""
        from copath.wire.keys import Keys

        from orchestrator.analysis.metrics import trace_from_records

        return trace_from_records(self.records, Keys(self.run_id))

    def poses(self) -> dict[str, np.ndarray]:
        """Per robot an (n, 4) array of the simulator's truth: t [s], x [m], y [m], theta [rad]."""
        return {n: np.column_stack([rt.t, rt.pose]) if len(rt.t) else np.zeros((0, 4))
                for n, rt in self.trace.robots.items()}

    def frame(self):
        """The truth as a pandas DataFrame (robot, t, x, y, theta, applied command u0..);
        needs pandas."""
        try:
            import pandas as pd
        except ImportError as exc:
            raise ImportError("Run.frame() needs pandas (pip install pandas); Run.poses() gives numpy arrays") from exc
        parts = []
        for n, rt in self.trace.robots.items():
            cols = {"robot": n, "t": rt.t, "x": rt.pose[:, 0], "y": rt.pose[:, 1], "theta": rt.pose[:, 2]}
            for j in range(rt.command.shape[1] if rt.command.ndim == 2 else 0):
                cols[f"u{j}"] = rt.command[:, j]
            parts.append(pd.DataFrame(cols))
        return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def run(scenario: Scenario | str | pathlib.Path, overrides: Mapping[str, Any] | Iterable[str] | None = None, *,
        inprocess: bool = False, out_dir: str | pathlib.Path | None = None, run_id: str | None = None,
        progress: bool = False, connect: tuple[str, ...] = (), listen: tuple[str, ...] = (),
        wall_timeout_s: float | None = None, on_tick: Callable[[float, int], None] | None = None,
        log: bool = True) -> Run:
    """Run a scenario in this process (lockstep, no Zenoh) or as a fleet of processes.

    A fleet run writes ``run.mcap``, ``metrics.json`` and ``scenario.json`` into
    ``out_dir`` (default ``runs/<run id>``); an in-process run writes ``metrics.json``
    and (unless ``log=False``) ``run.mcap`` there only when ``out_dir`` is given.
    """
    from copath.wire.keys import valid_run_id

    from orchestrator.run.fleet import new_run_id

    sc = load(scenario, overrides)
    rid = run_id or new_run_id(sc.id)
    valid_run_id(rid)
    if inprocess:
        from orchestrator.run.inprocess import run_scenario

        if sc.run.clock != "lockstep":
            raise ConfigError(f"run.clock = {sc.run.clock!r} is not allowed in-process; only lockstep runs in-process")
        res = run_scenario(sc, run_id=rid, on_tick=on_tick,  # its metrics carry ok and failure
                           log_dir=None if out_dir is None else pathlib.Path(out_dir) / "logs")
        out = None
        if out_dir is not None:
            from orchestrator.log.writer import write_records
            from orchestrator.view.foxglove import views_tap

            out = pathlib.Path(out_dir)
            out.mkdir(parents=True, exist_ok=True)
            (out / "metrics.json").write_text(json.dumps(res.metrics, indent=2))
            if log:
                write_records(out / "run.mcap", res.records, sc, rid, taps=[views_tap(sc)])
        return Run(sc, res.metrics, res.records, out, res.ok, res.metrics["failure"] or "completed")
    from orchestrator.run.fleet import RunOptions, run_fleet

    out = pathlib.Path(out_dir) if out_dir is not None else pathlib.Path("runs") / rid
    outcome = run_fleet(sc, RunOptions(out_dir=out, run_id=rid, progress=progress, connect=tuple(connect),
                                       listen=tuple(listen), wall_timeout_s=wall_timeout_s))
    return Run(sc, outcome.metrics or {}, outcome.records, out, outcome.ok, outcome.reason)


def open_run(path: str | pathlib.Path) -> Run:
    """A recorded run read back: a run directory or its ``run.mcap``. Metrics come from
    ``metrics.json`` next to the log, or are recomputed from the log (``copath metrics``)."""
    from orchestrator.log.mcap import read_log
    from orchestrator.analysis.metrics import metrics_from_log

    p = pathlib.Path(path)
    mcap = p / "run.mcap" if p.is_dir() else p
    if not mcap.is_file():
        raise FileNotFoundError(f"run log {str(mcap)!r} does not exist")
    log = read_log(mcap)
    sc = parse_scenario(log.scenario_raw, base_dir=None, source=log.scenario_raw.get("_source", ""))
    mfile = mcap.parent / "metrics.json"
    metrics = json.loads(mfile.read_text()) if mfile.is_file() else metrics_from_log(mcap)
    outcome = log.metadata.get("outcome", {})
    return Run(sc, metrics, log.records, mcap.parent, outcome.get("ok", "True") == "True",
               outcome.get("reason", "completed"))
