"""Scenario validation: every error names the key, the value and what is allowed."""

import pytest

from copath.scenario import ConfigError, load_scenario, parse_scenario
from tests.conftest import CONFIGS


def _base(**over):
    raw = {
        "id": "e5.5",
        "paths": {"main": {"type": "circle", "radius": 1.0}},
        "controller": {"type": "consensus"},
        "robots": [{"name": "r1", "path": "main", "neighbours": ["r2"]}, {"name": "r2", "path": "main", "pose": [0.0, 1.0, 0.0]}],
    }
    raw.update(over)
    return raw


def test_every_shipped_config_is_valid_and_named_by_its_experiment_id():
    """A reproduction names its experiment (``experiment``) and starts with its id; a variant
    of one (a box on the lane, a lost robot: docs/reference/detours.md) has no ``experiment``, so that
    the id still means the reproduction, and its name starts with that experiment's id."""
    files = sorted(CONFIGS.glob("*.toml"))
    assert files
    scenarios = {f: load_scenario(f) for f in files}
    reproduced = {s.experiment for s in scenarios.values() if s.experiment}
    for f, s in scenarios.items():
        if s.experiment:
            assert f.name.startswith(s.experiment + "-"), f.name
        else:
            assert f.name.split("-")[0] in reproduced, f.name
        assert s.id == f.stem


def test_scenarios_take_any_name_and_an_optional_experiment_id():
    s = parse_scenario(_base(id="my-test_2.b"))
    assert s.id == "my-test_2.b" and s.experiment is None
    assert parse_scenario(_base(experiment="e5.5")).experiment == "e5.5"


def test_neighbour_lists_are_made_symmetric():
    s = parse_scenario(_base())
    assert s.robot("r2").neighbours == ("r1",)
    assert s.edges() == [("r1", "r2")]


@pytest.mark.parametrize(
    "over, pattern",
    [
        ({"id": "my test!"}, r"id = 'my test!' is not allowed; expected a scenario name"),
        ({"experiment": "E5.5"}, r"experiment = 'E5.5' is not allowed; expected a dissertation experiment id"),
        ({"run": {"clock": "fast"}}, r"run.clock = 'fast' is not allowed; allowed: lockstep, realtime"),
        ({"run": {"dt": -1}}, r"run.dt = -1.0 is not allowed; must be > 0"),
        ({"run": {"dtt": 0.1}}, r"run.dtt = 0.1 is not allowed; allowed keys"),
        ({"network": {"loss": 1.5}}, r"network.loss = 1.5 is not allowed; must be a probability"),
        ({"controller": {"type": "no such thing"}}, r"controller.type = 'no such thing' is not allowed"),
        ({"robots": [{"name": "r1", "path": "nowhere"}]}, r"robots.r1.path = 'nowhere' is not allowed"),
        ({"robots": [{"name": "r1", "neighbours": ["r9"]}]}, r"robots.r1.neighbours = \['r9'\] is not allowed"),
        ({"robots": [{"name": "r1", "pose": [0, 0]}]}, r"robots.r1.pose = \[0, 0\] is not allowed; expected 3 numbers"),
        ({"robots": [{"name": "r1", "colour": "red"}]}, r"robots\[0\].colour = 'red' is not allowed"),
        ({"robots": [{"name": "r1"}, {"name": "r1"}]}, r"robots\[0\].name = 'r1' is not allowed; robot names must be unique"),
        ({"banana": 1}, r"banana = 1 is not allowed; allowed top-level keys"),
    ],
)
def test_bad_values_are_refused_with_key_value_and_rule(over, pattern):
    with pytest.raises(ConfigError, match=pattern):
        parse_scenario(_base(**over))


def test_unknown_controller_parameter_is_refused_when_the_controller_is_built():
    from agent.controllers import build_controller
    from copath.control import RobotContext
    from copath.models import UnicycleModel

    s = parse_scenario(_base(controller={"type": "consensus", "k7": 1.0}))
    r = s.robot("r1")
    ctx = RobotContext("r1", 0, UnicycleModel(), s.paths, "main", r.neighbours, s.robot_names, 0.1, r.params)
    with pytest.raises(ConfigError, match=r"robots.r1.controller.k7 = 1.0 is not allowed; allowed keys"):
        build_controller("consensus", ctx)


def test_overrides_are_validated_like_the_file():
    s = parse_scenario(_base())
    assert s.with_overrides(network={"delay_ms": 100}).network.delay_ms == 100
    with pytest.raises(ConfigError, match="network.jitter_ms = -3"):
        s.with_overrides(network={"jitter_ms": -3})


def test_data_files_are_read_into_the_scenario(tmp_path):
    (tmp_path / "shape.csv").write_text("x,y\n0,0\n1,0.5\n")
    (tmp_path / "s.toml").write_text(
        'id = "e5.5"\n[paths.main]\ntype = "circle"\nradius = 1.0\n[controller]\ntype = "consensus"\n'
        '[[robots]]\nname = "r1"\npath = "main"\n[robots.controller]\nshape_file = "shape.csv"\n'
    )
    s = load_scenario(tmp_path / "s.toml")
    assert s.robot("r1").params["shape"] == [[0.0, 0.0], [1.0, 0.5]]
    assert "shape_file" not in s.raw["robots"][0]["controller"]  # the raw table is self-contained
    (tmp_path / "bad.toml").write_text((tmp_path / "s.toml").read_text().replace("shape.csv", "missing.csv"))
    with pytest.raises(ConfigError, match="shape_file = 'missing.csv' is not allowed; no such file"):
        load_scenario(tmp_path / "bad.toml")


# --- issue 21: each problem once, with its line; offsets from one source ---

_TEAM = """
id = "t"
[paths.main]
type = "circle"
radius = 1.0
[controller]
type = "consensus"
k2 = 0.5
[[robots]]
name = "r1"
path = "main"
pose = [1.0, 0.0, 1.57]
neighbours = ["r2"]
controller = { s_d = 0.5 }
[[robots]]
name = "r2"
path = "main"
pose = [-1.0, 0.0, -1.57]
"""


def _errors(tmp_path, text):
    from orchestrator.run.validate import validate_file

    f = tmp_path / "t.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as e:
        validate_file(f)
    return e.value.errors


def test_a_typo_in_the_shared_controller_table_is_reported_once_with_its_line(tmp_path):
    errors = _errors(tmp_path, _TEAM.replace("k2 = 0.5", "k_two = 0.5"))
    assert len(errors) == 1, errors
    assert errors[0].startswith("line 8: controller.k_two = 0.5 is not allowed; allowed keys: ")


def test_a_robots_own_typo_names_the_robot_and_its_line(tmp_path):
    errors = _errors(tmp_path, _TEAM.replace("controller = { s_d = 0.5 }", "controller = { s_dd = 0.5 }"))
    assert errors == [e for e in errors if e.startswith("line 14: robots.r1.controller.s_dd = 0.5 is not allowed")]
    assert len(errors) == 1


def test_an_invalid_path_table_is_reported_once_without_a_cascade(tmp_path):
    errors = _errors(tmp_path, _TEAM.replace("radius = 1.0", "radius = -1.0"))
    assert errors == ["line 5: paths.main.radius = -1.0 is not allowed; a curve size must be a number > 0"]


def test_controller_offsets_and_declared_offsets_must_agree(tmp_path):
    base = _TEAM + "[metrics]\npath_offsets = { r1 = 0.5, r2 = 0.0 }\n"
    from orchestrator.run.validate import validate_file

    f = tmp_path / "ok.toml"
    f.write_text(base)
    assert validate_file(f).metrics["path_offsets"] == {"r1": 0.5, "r2": 0.0}  # r2: the default s_d = 0
    errors = _errors(tmp_path, base.replace("r1 = 0.5, r2 = 0.0", "r1 = 0.6, r2 = 0.25"))
    assert len(errors) == 2, errors
    assert "robots.r1.controller.s_d = 0.5 is not allowed; metrics.path_offsets.r1 = 0.6" in errors[0]
    assert "robot r1 (s_d given)" in errors[0]
    assert "robots.r2.controller.s_d = 0.0 is not allowed; metrics.path_offsets.r2 = 0.25" in errors[1]
    assert "(s_d its controller's default)" in errors[1]


def test_key_lines_place_tables_entries_by_index_and_name_and_inline_keys():
    from copath.scenario import key_lines

    lines = key_lines(_TEAM)
    assert lines["controller.k2"] == 8
    assert lines["robots[0].pose"] == lines["robots.r1.pose"] == 12
    assert lines["robots.r1.controller.s_d"] == 14
    assert lines["robots.r2.path"] == 17 and lines["paths.main.radius"] == 5


def test_key_lines_follow_sub_tables_of_the_last_array_entry():
    from copath.scenario import key_lines

    text = '[[robots]]\nname = "r1"\n[robots.controller]\ns_d = 1.2\n[[robots]]\nname = "r2"\n[robots.controller]\ns_d = 0.6\n'
    lines = key_lines(text)
    assert lines["robots.r1.controller.s_d"] == 4 and lines["robots.r2.controller.s_d"] == 8


def test_key_lines_skip_the_rows_of_a_multi_line_array():
    from copath.scenario import key_lines

    text = '[paths.s]\ntype = "spline"\nwaypoints = [\n  [0.0, 0.0],\n  [1.0, 1.0],\n  [2.0, 0.0],\n]\nclosed = true\n[run]\ndt = 0.1\n'
    lines = key_lines(text)
    assert lines["paths.s.waypoints"] == 3 and lines["paths.s.closed"] == 8 and lines["run.dt"] == 10
    assert not any(k.startswith("0") for k in lines)


def test_run_kills_are_checked_at_the_edge_naming_key_value_and_what_is_allowed():
    """``run.kills`` (docs/reference/faults.md, "A kill declared in the scenario"): each a table
    {robot, at_s} naming a robot of the scenario, at a time > 0, once."""
    import tomllib  # noqa: PLC0415

    from copath.scenario import ConfigError, Kill, parse_scenario  # noqa: PLC0415
    from tests.conftest import config  # noqa: PLC0415

    raw = tomllib.loads(config("e5.4-six-robots-lemniscate").read_text())
    raw["run"]["kills"] = [{"robot": "r1", "at_s": 10}, {"robot": "r1", "at_s": 20.5}]
    assert parse_scenario(raw).run.kills == (Kill("r1", 10.0), Kill("r1", 20.5))
    for bad, said in [([{"robot": "r9", "at_s": 10}], "run.kills[0].robot = 'r9' is not allowed; must name a robot"),
                      ([{"robot": "r1", "at_s": 0}], "run.kills[0].at_s = 0 is not allowed; expected a time [s] > 0"),
                      ([{"robot": "r1", "at_s": True}], "run.kills[0].at_s = True is not allowed"),
                      ([{"robot": "r1"}], "run.kills[0].at_s = None is not allowed"),
                      ([{"robot": "r1", "at_s": 5, "signal": 9}], "run.kills[0].signal = 9 is not allowed; allowed keys: robot, at_s"),
                      ("r1", "run.kills = 'r1' is not allowed; expected a list of tables {robot, at_s}"),
                      ([{"robot": "r1", "at_s": 5}, {"robot": "r1", "at_s": 5.0}], "is declared twice")]:
        raw["run"]["kills"] = bad
        with pytest.raises(ConfigError) as err:
            parse_scenario(raw)
        assert said in str(err.value), (bad, str(err.value))
