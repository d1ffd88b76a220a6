"""The reference pages say what the code does: docs/reference/scenarios.md, docs/reference/controller-parameters.md,
the Path API of docs/reference/controllers.md and the metrics.json keys of docs/reference/metrics.md."""

from __future__ import annotations

import dataclasses
import pathlib
import re

import pytest

from copath.estimation import EstimatorConfig, SensorProfile
from copath.metrics_config import MetricsConfig
from copath.models import MODEL_TYPES
from copath.paths import PATH_TYPES, Path, PathTable
from copath.ros2.config import RobotIO, WorldConfig
from copath.safety import SafetyConfig
from copath.scenario import (_ROBOT_KEYS, _TOP_KEYS, Kill, NetworkConfig, NoiseConfig, ObstacleSpec, Partition, RunConfig,
                             SensorConfig, Silence, parse_scenario)
from copath.grading import AT_MOST, TARGETS
from orchestrator import reference
from orchestrator.run.inprocess import run_scenario
from orchestrator.analysis.metrics import FLEET_KEYS, ROBOT_KEYS

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs" / "reference"


def _section(text: str, name: str) -> str:
    """The part of a page under the ``## `` heading that names `name`."""
    for part in text.split("\n## ")[1:]:
        if f"`{name}`" in part.split("\n", 1)[0]:
            return part
    raise AssertionError(f"no section for {name} in the page")


def _rows(text: str) -> dict[str, str]:
    """Markdown table rows by their first cell's code name (`key`)."""
    return {m.group(1): m.group(0) for m in re.finditer(r"^\| `([\w.\-<>]+)`[^\n]*", text, re.M)}


@pytest.mark.parametrize("page", reference.PAGES)
def test_committed_pages_are_what_the_code_generates(page):
    text = (DOCS.parent / page).read_text()
    assert reference.blocks_in(text), f"docs/{page} has no generated block"
    assert reference.render(text) == text, f"docs/{page} is out of date: run python -m orchestrator.reference"


def test_every_generated_block_is_on_a_page():
    shown = [b for page in reference.PAGES for b in reference.blocks_in((DOCS.parent / page).read_text())]
    assert sorted(shown) == sorted(reference.BLOCKS)


@pytest.mark.parametrize("cls, section", [
    (RunConfig, "[run]"), (Kill, "[run]"), (NetworkConfig, "[network]"), (Partition, "[network]"), (Silence, "[network]"),
    (NoiseConfig, "[noise]"), (SensorConfig, "[sensors]"), (EstimatorConfig, "[sensing]"),
    (SensorProfile, "[sensing]"), (ObstacleSpec, "[[obstacles]]"), (MetricsConfig, "[metrics]"),
    (SafetyConfig, "[safety]"), (WorldConfig, "[world]"), *[(cls, "[[robots]]") for cls in MODEL_TYPES.values()],
])
def test_every_key_of_every_table_is_documented_with_its_default(cls, section):
    text = (DOCS / "scenarios.md").read_text()
    part = _section(text, section)
    kind = next((k for k, c in MODEL_TYPES.items() if c is cls), None)
    if kind is not None:  # one table per model type
        part = part.split(f'`model = "{kind}"` or')[1].split('\n`model = "')[0]
    rows = _rows(part)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        assert f.name in rows, f"{section} {f.name} is not in docs/reference/scenarios.md"
        assert f"`{reference.default_text(f)}`" in rows[f.name], f"{section} {f.name}: default not shown"


def test_no_documented_key_is_unknown():
    text = (DOCS / "scenarios.md").read_text()
    known = {f.name for cls in (RunConfig, Kill, NetworkConfig, Partition, Silence, NoiseConfig, SensorConfig,
                                EstimatorConfig, SensorProfile, ObstacleSpec, MetricsConfig, SafetyConfig,
                                WorldConfig, RobotIO, *MODEL_TYPES.values()) for f in dataclasses.fields(cls)}
    known |= set(_TOP_KEYS) | set(_ROBOT_KEYS) | set(TARGETS) | {"profile", "estimator", "solve_time_s", "robots",
                                                               "pose_type"}
    assert set(_rows(text)) <= known, set(_rows(text)) - known


def test_top_level_and_robot_keys_are_documented():
    text = (DOCS / "scenarios.md").read_text()
    top = text.split("## Top level")[1].split("\n## ")[0]
    for k in _TOP_KEYS - {"_source"}:
        assert f"`{k}`" in top, k
    robots = _rows(_section(text, "[[robots]]"))
    assert _ROBOT_KEYS <= set(robots)


def test_every_path_type_has_its_keys_and_a_figure():
    text = (DOCS / "scenarios.md").read_text()
    for kind in PATH_TYPES:
        assert f"**`{kind}`**" in text and f"(../img/path-{kind}.png)" in text, kind
        assert (DOCS.parent / "img" / f"path-{kind}.png").stat().st_size > 1000, kind


def test_every_target_is_documented_with_its_direction():
    rows = _rows(_section((DOCS / "scenarios.md").read_text(), "[targets]"))
    for key, (scope, sense) in TARGETS.items():
        assert key in rows, key
        assert ("maximum" if sense == AT_MOST else "minimum") in rows[key], key
        assert ("worst robot" if scope == "robots" else "fleet") in rows[key], key


def test_neighbours_semantics_are_stated_and_true():
    text = (DOCS / "scenarios.md").read_text()
    assert "hears r2 **and** r2 hears r1" in text
    # the claim: one listing makes an undirected edge
    s = parse_scenario({"id": "n", "paths": {"c": {"type": "circle", "radius": 1.0}},
                        "controller": {"type": "consensus"},
                        "robots": [{"name": "r1", "pose": [1, 0, 0], "path": "c", "neighbours": ["r2"]},
                                   {"name": "r2", "pose": [-1, 0, 0], "path": "c"}]})
    assert s.robot("r2").neighbours == ("r1",) and s.robot("r1").neighbours == ("r2",)


def test_every_public_member_of_path_is_in_the_controller_guide():
    text = (DOCS / "controllers.md").read_text()
    path = Path.__new__(Path)  # attributes set in __init__ count too
    names = {n for n in dir(Path) if not n.startswith("_")} | set(reference._PATH_ATTRS)
    for n in names:
        assert f"`Path.{n}" in text, f"Path.{n} is not in docs/reference/controllers.md"
    for n in (n for n in dir(PathTable) if not n.startswith("_")):
        assert f"`PathTable.{n}" in text, f"PathTable.{n} is not in docs/reference/controllers.md"
    assert path is not None


def _metrics_reference() -> dict[str, set[str]]:
    text = (DOCS / "metrics.md").read_text().split("## Every key of metrics.json")[1]
    parts = re.split(r"^### ", text, flags=re.M)[1:]
    out = {}
    for part in parts:
        scope = "top" if part.startswith("Top level") else "robots" if part.startswith("Per robot") else "fleet"
        out[scope] = set(_rows(part))
    return out


def test_every_metrics_key_a_run_emits_is_documented():
    """A short in-process run (0.3 s, two consensus robots): every key it writes is in
    docs/reference/metrics.md, and every key documented there is one the code knows."""
    raw = {"id": "ref-keys", "run": {"duration_s": 0.3, "dt": 0.1},
           "paths": {"c": {"type": "circle", "radius": 1.0}},
           "controller": {"type": "consensus"},
           "robots": [{"name": "r1", "pose": [1.0, 0.0, 1.57], "path": "c", "neighbours": ["r2"]},
                      {"name": "r2", "pose": [0.0, 1.0, 3.14], "path": "c"}]}
    m = run_scenario(parse_scenario(raw)).metrics
    doc = _metrics_reference()
    assert set(m) - doc["top"] == set(), f"top-level keys not in docs/reference/metrics.md: {set(m) - doc['top']}"
    emitted = set().union(*(set(v) for v in m["robots"].values()))
    assert emitted - doc["robots"] == set(), f"per-robot keys not in docs/reference/metrics.md: {emitted - doc['robots']}"
    assert set(m["fleet"]) - doc["fleet"] == set(), f"fleet keys not in docs/reference/metrics.md: {set(m['fleet']) - doc['fleet']}"
    # and nothing documented is unknown (roles teams add three per-task keys)
    roles_extra = {"assignment_cost_per_task", "assignment_cost_optimal_per_task", "assignment_duplicates"}
    assert doc["robots"] <= set(ROBOT_KEYS) | emitted
    assert doc["fleet"] <= set(FLEET_KEYS) | set(m["fleet"]) | roles_extra
    assert doc["top"] <= set(m)
    assert set(ROBOT_KEYS) <= doc["robots"] and set(FLEET_KEYS) <= doc["fleet"]


def test_the_example_of_the_scenario_reference_is_valid(tmp_path):
    from orchestrator.run.validate import validate_file

    text = (DOCS / "scenarios.md").read_text()
    example = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    f = tmp_path / "example.toml"
    f.write_text(example)
    s = validate_file(f)
    assert s.robot("r2").neighbours == ("r1",) and s.robot("r1").params["s_d"] == 0.75
