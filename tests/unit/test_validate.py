"""``copath validate`` and the first step of ``copath run``: every problem of a scenario, at
once, with its key path, value and rule; exit code 2; nothing started."""

from __future__ import annotations

import pathlib

import pytest

from orchestrator.cli import main
from tests.conftest import CONFIGS

GOOD = """
id = "my-test"
[run]
duration_s = 10.0
settle_s = 5.0
[paths.main]
type = "lemniscate"
a = 2.3
[controller]
type = "consensus"
[[robots]]
name = "r1"
path = "main"
pose = [0.0, 0.0, 0.0]
neighbours = ["r2"]
[[robots]]
name = "r2"
path = "main"
pose = [0.5, 0.0, 0.0]
neighbours = ["r3"]
[[robots]]
name = "r3"
path = "main"
pose = [1.0, 0.0, 0.0]
"""

# (what is broken, how the file is changed, the one-line error expected)
BROKEN = [
    ("controller parameter typo", lambda s: s.replace('type = "consensus"', 'type = "consensus"\nk_one = 5.0'),
     r"line 11: controller\.k_one = 5\.0 is not allowed; allowed keys: .*k1"),  # once, not per robot
    ("settle after the end", lambda s: s.replace("settle_s = 5.0", "settle_s = 12.0"),
     r"run\.settle_s = 12\.0 is not allowed; must be less than run\.duration_s = 10\.0"),
    ("negative curve size", lambda s: s.replace("a = 2.3", "a = -2.3"),
     r"paths\.main\.a = -2\.3 is not allowed; a curve size must be a number > 0"),
    ("overlapping start poses", lambda s: s.replace("pose = [0.5, 0.0, 0.0]", "pose = [0.05, 0.0, 0.0]"),
     r"robots\.r2\.pose = \[0\.05, 0\.0, 0\.0\] is not allowed; starts 0\.050 m from robots\.r1 .* at least the "
     r"sum of the two radii apart"),
    ("controller needs a path", lambda s: s.replace('name = "r3"\npath = "main"', 'name = "r3"'),
     r"robots\.r3\.path = None is not allowed; controller type 'consensus' needs a path"),
    ("partition on a non-edge", lambda s: s + '[network]\npartitions = [{links = [["r1", "r3"]], start_s = 1.0}]\n',
     r"network\.partitions\[0\]\.links = \['r1', 'r3'\] is not allowed; must be an edge of the communication graph"),
    ("partition names a stranger", lambda s: s + '[network]\npartitions = [{links = [["r1", "r9"]]}]\n',
     r"network\.partitions\[0\]\.links = \['r1', 'r9'\] is not allowed; must name two robots"),
    ("unknown controller", lambda s: s.replace('type = "consensus"', 'type = "consensos"'),
     r"line 10: controller\.type = 'consensos' is not allowed; registered: .*consensus"),
    ("import path to nowhere", lambda s: s.replace('type = "consensus"', 'type = "no_such_pkg.law:build"'),
     r"controller\.type = 'no_such_pkg\.law:build' is not allowed; no module named 'no_such_pkg'"),
    ("declared geometry misses a robot", lambda s: s + '[metrics]\npath_offsets = { r1 = 0.0, r2 = 0.5 }\n',
     r"metrics\.path_offsets = \{'r1': 0\.0, 'r2': 0\.5\} is not allowed; must give an offset for each robot: "
     r"r1, r2, r3"),
    ("model the controller cannot drive", lambda s: s.replace('type = "consensus"', 'type = "dmpc"'),
     r"robots\.r1\.model = 'unicycle' is not allowed; controller type 'dmpc' drives: omni"),
]


def _write(tmp_path: pathlib.Path, text: str, name: str = "s.toml") -> str:
    f = tmp_path / name
    f.write_text(text)
    return str(f)


def test_a_good_scenario_validates(tmp_path, capsys):
    assert main(["validate", _write(tmp_path, GOOD)]) == 0
    assert "ok (my-test, 3 robots, controllers: consensus)" in capsys.readouterr().out


def test_every_bundled_scenario_validates(capsys):
    files = sorted(str(f) for f in CONFIGS.glob("*.toml"))
    assert main(["validate", *files]) == 0
    assert capsys.readouterr().out.count(": ok (") == len(files)


@pytest.mark.parametrize("what, change, pattern", BROKEN, ids=[b[0] for b in BROKEN])
def test_each_rule_gives_one_clear_line_and_exit_code_2(tmp_path, capsys, what, change, pattern):
    import re

    assert main(["validate", _write(tmp_path, change(GOOD))]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if re.search(pattern, line)]
    assert len(lines) == 1, err


def test_all_problems_are_reported_at_once_and_run_starts_nothing(tmp_path, capsys):
    text = GOOD
    for _, change, _ in BROKEN[:5]:
        text = change(text)
    f = _write(tmp_path, text)
    out = tmp_path / "out"
    assert main(["run", f, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    for _, _, pattern in BROKEN[:4]:  # r3 keeps its path in this combination
        import re

        assert re.search(pattern, err), (pattern, err)
    assert "problems; nothing was started" in err
    assert not out.exists()  # no run directory, no router, no process
