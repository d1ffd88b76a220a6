"""The command line driven in-process: scenario look-up, --set, targets and --check,
progress, sweeps, --version and --log-level (orchestrator/cli.py, api.py, sweep.py)."""

from __future__ import annotations

import csv
import io
import json

import pytest

from copath.config import ConfigError
from copath.grading import TARGETS, Target, grade, parse_targets
from orchestrator import api
from orchestrator.studies import sweep
from orchestrator.cli import main as copath
from orchestrator.analysis.metrics import METRIC_KEYS
from orchestrator.run.progress import Progress

SHORT = ["--set", "run.duration_s=3", "--set", "run.settle_s=1", "-q"]


# --- finding scenarios ---

def test_every_bundled_scenario_is_found_by_stem_and_unique_experiment_id():
    bundled = api.bundled_scenarios()
    assert len(bundled) >= 20
    by_exp: dict[str, list[str]] = {}
    for b in bundled:
        assert api.find_scenario(b.stem) == b.path
        by_exp.setdefault(b.experiment, []).append(b.stem)
    for exp, stems in by_exp.items():
        if exp is not None and len(stems) == 1:
            assert api.find_scenario(exp).stem == stems[0]
            assert api.find_scenario(exp.upper()).stem == stems[0]


def test_an_experiment_with_several_scenarios_lists_them():
    with pytest.raises(ConfigError) as e:
        api.find_scenario("e4.4")
    msg = str(e.value)
    assert "e4.4" in msg and msg.count("e4.4-unicycle-nmpc") == 3


def test_an_unknown_scenario_names_what_is_allowed(tmp_path):
    with pytest.raises(ConfigError, match=r"scenario = 'e9\.9' is not allowed;.*e5\.5"):
        api.find_scenario("e9.9")
    with pytest.raises(ConfigError, match="does not exist"):
        api.find_scenario(str(tmp_path / "missing.toml"))


def test_scenarios_lists_every_bundled_file(capsys):
    assert copath(["scenarios", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {r["stem"] for r in rows} == {b.stem for b in api.bundled_scenarios()}
    assert all(r["error"] is None for r in rows), [r for r in rows if r["error"]]


# --- overrides ---

def test_set_values_are_toml_literals_applied_anywhere():
    s = api.load("e5.5", ["network.loss=0.1", "run.clock=realtime", "robots.r2.pose=[2.2, 0.7, 2.1]",
                          "robots[0].controller.s_d=1.4", 'title="changed"'])
    assert s.network.loss == 0.1 and s.run.clock == "realtime" and s.title == "changed"
    assert s.robot("r2").pose == (2.2, 0.7, 2.1)
    assert s.robot("r1").params["s_d"] == 1.4


@pytest.mark.parametrize("item, needle", [
    ("network.loss=1.5", "network.loss = 1.5 is not allowed; must be a probability"),
    ("network.los=0.1", "network.los = 0.1 is not allowed; allowed keys"),
    ("controller.k_one=1", "controller.k_one = 1 is not allowed"),
    ("robots.r9.pose=[0,0,0]", "robots.r9.pose = [0, 0, 0] is not allowed; robots has no entry 'r9'"),
    ("run.duration_s", "expected key.path=value"),
])
def test_a_bad_set_names_key_value_and_rule(item, needle, capsys, tmp_path):
    assert copath(["run", "e5.5", "--inprocess", "--out", str(tmp_path), "--set", item]) == 2
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "metrics.json").exists()


# --- runs, targets, --check ---

def test_run_by_experiment_id_inprocess_writes_metrics_and_shows_progress(tmp_path, capsys):
    assert copath(["run", "e5.5", "--inprocess", "--out", str(tmp_path), *SHORT[:-1]]) == 0
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["scenario"] == "e5.5-column-lemniscate" and m["sim_time_s"] == pytest.approx(3.0)
    err = capsys.readouterr().err
    assert "3.0/3.0 s sim" in err and "real time" in err and "msg/s" in err and "ETA" in err


def test_check_fails_on_a_missed_target_and_passes_a_met_one(tmp_path, capsys):
    args = ["run", "e5.5", "--inprocess", "--out", str(tmp_path), *SHORT]
    assert copath([*args, "--set", "targets={collisions = 0, coordination_error_max_m = 1e-9}", "--check"]) == 3
    out = capsys.readouterr()
    assert "PASS  collisions" in out.out and "MISS  coordination_error_max_m" in out.out
    assert "coordination_error_max_m" in out.err
    # without --check a missed target is reported, not an error
    assert copath([*args, "--set", "targets.coordination_error_max_m=1e-9"]) == 0
    assert copath([*args, "--set", "targets={coordination_error_max_m = 10.0}", "--check"]) == 0
    assert "targets (1/1 met)" in capsys.readouterr().out


def test_targets_are_validated_against_metric_keys():
    with pytest.raises(ConfigError, match=r"targets\.coordination_eror_m = 0\.1 is not allowed; allowed metric keys"):
        parse_targets({"coordination_eror_m": 0.1})
    with pytest.raises(ConfigError, match="expected a finite number"):
        parse_targets({"collisions": "none"})
    known = set(METRIC_KEYS["robots"]) | set(METRIC_KEYS["fleet"])
    assert set(TARGETS) <= known
    for key, (scope, _) in TARGETS.items():
        assert key in METRIC_KEYS[scope]


def test_grade_uses_the_worst_robot_and_the_sense_of_each_metric():
    metrics = {"robots": {"a": {"path_error_max_m": 0.05}, "b": {"path_error_max_m": 0.2}},
               "fleet": {"min_separation_m": 0.3, "tasks_completed": None}}
    r = grade((Target("path_error_max_m", 0.1), Target("min_separation_m", 0.25), Target("tasks_completed", 1)),
              metrics)
    assert (r[0].passed, r[0].value, r[0].worst) == (False, 0.2, "b")
    assert r[1].passed and r[1].value == 0.3
    assert not r[2].passed and r[2].value is None  # not measured is not met


def test_every_bundled_scenario_has_targets():
    for b in api.bundled_scenarios():
        assert api.load(b.path).targets, f"{b.stem} has no [targets]"


# --- sweep ---

def test_seeds_and_axes_parse():
    assert sweep.parse_seeds("1-3,7") == [1, 2, 3, 7]
    with pytest.raises(ConfigError, match="--seeds"):
        sweep.parse_seeds("1-x")
    axes = sweep.parse_axes(["network.loss=0,0.1,0.2", "noise.pose_std=[0,0,0],[0.01,0.01,0]"])
    assert axes == [("network.loss", [0, 0.1, 0.2]), ("noise.pose_std", [[0, 0, 0], [0.01, 0.01, 0]])]
    assert len(sweep.plan(axes, [1, 2, 3])) == 18
    with pytest.raises(ConfigError, match="--seeds"):
        sweep.parse_axes(["run.seed=1,2"])


def test_sweep_inprocess_writes_table_summary_and_plots(tmp_path, capsys):
    rc = copath(["sweep", "e5.5", "--inprocess", "--jobs", "1", "--seeds", "1-2", "--set", "network.loss=0,0.3",
                 "--set", "run.duration_s=3", "--set", "run.settle_s=1", "--out", str(tmp_path), "-q"])
    assert rc == 0
    rows = list(csv.DictReader((tmp_path / "sweep.csv").open()))
    assert len(rows) == 4
    assert [r["network.loss"] for r in rows] == ["0", "0", "0.3", "0.3"]
    assert [r["run.seed"] for r in rows] == ["1", "2", "1", "2"]
    assert all(r["ok"] == "True" for r in rows)
    dropped = {r["network.loss"]: float(r["messages_dropped_by_faults"]) for r in rows}
    assert dropped["0"] == 0 and dropped["0.3"] > 0  # the faults were applied
    out = capsys.readouterr().out
    assert "mean/worst" in out and (tmp_path / "summary.txt").read_text().strip() in out
    assert (tmp_path / "sweep-coordination_error_max_m.png").stat().st_size > 1000


def test_sweep_rejects_a_bad_value_before_running(tmp_path, capsys):
    assert copath(["sweep", "e5.5", "--inprocess", "--set", "network.loss=0,2", "--out", str(tmp_path)]) == 2
    assert "network.loss = 2" in capsys.readouterr().err
    assert not (tmp_path / "sweep.csv").exists()


# --- progress ---

def test_progress_reports_rate_real_time_factor_and_eta():
    buf = io.StringIO()
    p = Progress(10.0, stream=buf, interval_s=0.01)
    assert "starting" in p.line()
    p.update(0.0, 0)
    p._first_tick = p.t0 - 1.0  # pretend 1 s of running
    p.update(2.0, 100)
    f = p.figures()
    assert f["rtf"] == pytest.approx(2.0, rel=0.2)
    assert f["eta"] == pytest.approx(4.0, rel=0.2)
    p.update(5.0, 300)
    assert "5.0/10.0 s sim" in buf.getvalue()  # not a terminal: one line per tenth


# --- version and logging ---

def test_version_and_log_level(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        copath(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("copath ")
    assert copath(["--log-level", "debug", "scenarios", "--json"]) == 0
    assert copath(["scenarios", "--log-level", "info", "--json"]) == 0
    with pytest.raises(SystemExit):
        copath(["--log-level", "loud", "scenarios"])



# --- the Python API and info on a logged run ---

def test_api_run_log_reads_back_and_info_shows_the_run(tmp_path, capsys):
    run = api.run("e5.5", ["run.duration_s=3", "run.settle_s=1", "network.loss=0.2", "run.seed=7"],
                  inprocess=True, out_dir=tmp_path)
    poses = run.poses()
    assert set(poses) == {"r1", "r2", "r3"}
    assert poses["r1"].shape == (30, 4) and poses["r1"][-1, 0] == pytest.approx(2.9)
    back = api.open_run(tmp_path)
    assert back.metrics == run.metrics
    assert back.scenario.network.loss == 0.2 and back.scenario.run.seed == 7
    for name in poses:
        assert (back.poses()[name] == poses[name]).all()
    assert [r.passed for r in back.grade()] == [r.passed for r in run.grade()]
    assert copath(["info", str(tmp_path / "run.mcap")]) == 0  # both wall-clock spans, each said what it is
    out = capsys.readouterr().out
    assert "(wall clock, first to last message of the log)" in out
    assert f"Run time:     {run.metrics['wall_time_s']:.1f} s (wall clock, metrics.json wall_time_s" in out
    (tmp_path / "metrics.json").unlink()  # info computes the figures from the log alone
    assert copath(["info", str(tmp_path / "run.mcap")]) == 0
    out = capsys.readouterr().out
    assert "Seed:         7" in out and "network.loss=0.2" in out and "Sim time:     3.00 s" in out
    assert f"coordination_error_max_m={run.metrics['fleet']['coordination_error_max_m']:.4f}" in out
    assert copath(["info", str(tmp_path / "run.mcap"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["seed"] == 7 and info["faults"] == {"network.loss": 0.2}
    assert info["headline"]["collisions"] == run.metrics["fleet"]["collisions"]


def test_api_frame_is_a_dataframe_where_pandas_is_installed():
    pd = pytest.importorskip("pandas")
    run = api.run("e5.5", {"run.duration_s": 2.0, "run.settle_s": 1.0}, inprocess=True)
    df = run.frame()
    assert isinstance(df, pd.DataFrame) and len(df) == 3 * 20
    assert {"robot", "t", "x", "y", "theta"} <= set(df.columns)


# --- issue 21: the CLI items ---

_VALID = """
id = "v"
[run]
duration_s = 10.0
[paths.main]
type = "circle"
radius = 1.0
[controller]
type = "consensus"
[[robots]]
name = "r1"
path = "main"
pose = [1.0, 0.0, 1.57]
neighbours = ["r2"]
[[robots]]
name = "r2"
path = "main"
pose = [-1.0, 0.0, -1.57]
"""


def test_validate_takes_set_like_run(tmp_path, capsys):
    f = tmp_path / "v.toml"
    f.write_text(_VALID)
    assert copath(["validate", str(f), "--set", "network.loss=0.2", "--set", "controller.v0=0.3"]) == 0
    assert "ok (v, 2 robots" in capsys.readouterr().out
    assert copath(["validate", str(f), "--set", "network.loss=2", "--set", "controller.v0=-1"]) == 2
    err = capsys.readouterr().err
    assert "network.loss = 2.0 is not allowed; must be a probability in [0, 1]" in err
    assert err.count("v0 = -1.0 is not allowed") == 1 and "controller.v0 = -1.0" in err  # once, not per robot
    assert "line " not in err  # a value given with --set has no line in the file
    assert copath(["validate", str(f), "--set", "nonsense"]) == 2


def test_a_reader_that_goes_away_ends_the_output_quietly():
    """``copath controllers | head``: the pipe closes before copath writes; no traceback."""
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-m", "orchestrator", "controllers"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before the first line is written
    try:
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert b"Traceback" not in err and b"BrokenPipeError" not in err, err.decode()
    assert p.returncode == 1


def test_controllers_lists_each_parameter_with_type_default_and_meaning(capsys):
    assert copath(["controllers", "consensus"]) == 0
    out = capsys.readouterr().out
    assert "v0 (number, default 0.2): Group speed" in out
    assert "s0 (number (optional), default (none)): Initial path coordinate" in out
    assert copath(["controllers", "no_such_law"]) == 2


def test_animation_progress_is_plain_lines_when_not_a_terminal():
    from orchestrator.view.plot import animation_bar

    class Tty(io.StringIO):
        def isatty(self):
            return True

    log, tty = io.StringIO(), Tty()
    for bar in (animation_bar(log), animation_bar(tty)):
        for i in range(200):
            bar(i, 200)
    assert "\r" not in log.getvalue()
    assert len(log.getvalue().splitlines()) == 11  # the first frame and every tenth
    assert tty.getvalue().count("\r") == 200


def test_faults_title_says_what_each_count_is():
    from orchestrator.view.plot import faults_caption

    text = faults_caption(967, 964)
    assert "967 replayed from the log" in text and "964 counted by the receivers" in text
    assert "in flight at the end" in text
    assert faults_caption(12, 12) == "12 (replayed from the log = the receivers' own count)"


def test_sweep_plots_draw_the_scenarios_target(tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    kept = []
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    rows = [sweep.SweepRow(i, {"network.loss": loss}, f"r{i}", True, None,
                           {"coordination_error_max_m": 0.01 + loss, "collisions": 0}, 1, 1, 1.0)
            for i, loss in enumerate((0.0, 0.1, 0.2))]
    sweep.plot_sweep(rows, tmp_path, {"coordination_error_max_m": 0.02})
    lines = {fig.axes[0].get_ylabel(): [ln.get_label() for ln in fig.axes[0].get_lines()] for fig in kept}
    assert "target: at most 0.02" in lines["coordination_error_max_m"]
    assert not any(lb.startswith("target") for lb in lines["collisions"])  # no target for it


def test_run_scenario_metrics_say_ok_like_api_run():
    from orchestrator.run.inprocess import run_scenario

    s = api.load("e5.5", {"run.duration_s": 0.5, "run.settle_s": 0.0})
    res = run_scenario(s)
    assert res.metrics["ok"] is True and res.metrics["failure"] is None
    run = api.run(s, inprocess=True)
    assert run.metrics["ok"] is True and run.ok


def test_validate_takes_a_bundled_name_like_run(capsys):
    """``copath validate e5.5`` means the bundled scenario ``copath run e5.5`` runs."""
    assert copath(["validate", "e5.5", "e5.4-six-robots-lemniscate"]) == 0
    out = capsys.readouterr().out
    assert "e5.5: ok (e5.5-column-lemniscate, 3 robots" in out
    assert "e5.4-six-robots-lemniscate: ok (e5.4-six-robots-lemniscate, 6 robots" in out
    assert copath(["validate", "e9.9"]) == 2
    assert "expected a scenario file, a bundled scenario's file stem or an experiment id" in capsys.readouterr().err


def test_the_command_line_loads_its_subcommands_lazily():
    """``copath --help`` (the parser built) loads the scenario parser and the API, and none of
    the run, log, view, analysis or study modules, nor Zenoh, Foxglove, CasADi or Matplotlib:
    each subcommand imports what it needs when it runs."""
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    from tests.conftest import REPO  # noqa: PLC0415

    probe = ("import sys; from orchestrator.cli import build_parser; build_parser(); "
             "print(' '.join(sorted(sys.modules)))")
    loaded = set(subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True,
                                cwd=str(REPO)).stdout.split())
    heavy = ("orchestrator.run", "orchestrator.log", "orchestrator.view", "orchestrator.analysis",
             "orchestrator.studies.sweep", "orchestrator.studies.envelope", "zenoh", "foxglove", "casadi",
             "matplotlib", "agent", "sim")
    assert "orchestrator.cli" in loaded
    assert not sorted(m for m in loaded if any(m == h or m.startswith(h + ".") for h in heavy))
