"""``copath plot``: every figure family renders (Agg) from a recorded run of each
controller family, only where it applies; dropped messages reconstructed from the log
match the processes' closing accounts."""

from __future__ import annotations

import json

import pytest

from copath.scenario import load_scenario
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.writer import write_records
from orchestrator.view.plot import FAMILIES, animate_run, applicable, drops, load_run, plot_run
from tests.conftest import config

PNG = b"\x89PNG\r\n\x1a\n"
FAULTS = {"loss": 0.2, "partitions": [{"links": [["r1", "r2"]], "start_s": 0.5, "end_s": 1.2}]}

# config prefix -> (run length [s], network overrides, families that must appear)
CASES = {
    "e4.2-": (1.0, None, {"tracking", "speeds", "solve_times"}),  # omni NMPC
    "e4.3-": (1.0, None, {"tracking", "speeds", "solve_times"}),  # LTV MPC (QP)
    "e4.4-unicycle-nmpc-pf": (1.0, None, {"tracking", "speeds", "solve_times"}),  # unicycle NMPC
    "e5.1-": (1.0, None, {"tracking", "coordination", "solve_times"}),  # leader-following NMPC
    "e5.2-": (1.5, FAULTS, {"tracking", "coordination", "solve_times", "faults"}),  # distributed MPC
    "e5.4-": (1.0, None, {"tracking", "speeds", "coordination"}),  # consensus
    "e5.7-": (1.0, None, {"tracking", "coordination"}),  # heterogeneous team
    "e6.5-": (1.0, None, {"tasks"}),  # roles (Ch. 6)
    "e6.6-": (1.0, None, {"tracking", "coordination", "tasks"}),  # formation switching
}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """prefix -> (scenario, run log) of a short in-process run, each recorded once."""
    cache = {}

    def get(prefix):
        if prefix not in cache:
            duration, network, _ = CASES[prefix]
            s = load_scenario(config(prefix))
            if network:
                s = s.with_overrides(network=network)
            res = run_scenario(s, duration_s=duration, run_id="plot")
            cache[prefix] = s, write_records(tmp_path_factory.mktemp("run") / "run.mcap", res.records, s, "plot")
        return cache[prefix]

    return get


@pytest.mark.parametrize("prefix", list(CASES))
def test_every_applicable_family_renders(tmp_path, recorded, prefix):
    _, network, must = CASES[prefix]
    s, log = recorded(prefix)
    files = plot_run(log, tmp_path / "plots", dpi=40)
    layout = json.loads((tmp_path / "plots" / "foxglove-layout.json").read_text())
    assert layout["content"]["items"][0]["content"]["panelType"] == "ThreeDee"
    files = [f for f in files if f.suffix == ".png"]
    names = {f.stem for f in files}
    assert {"snapshots", "velocities"} | must <= names
    assert names <= set(FAMILIES)
    if len(s.robots) == 1:
        assert "coordination" not in names
    if not network:
        assert "faults" not in names
    for f in files:
        assert f.read_bytes()[:8] == PNG and f.stat().st_size > 2000, f


def test_drops_reconstructed_from_the_log_match_the_closing_accounts(recorded):
    s, log = recorded("e5.2-")
    view = load_run(log)
    ds = drops(view)
    assert ds.accounted is not None and len(ds.t) == ds.accounted > 0
    p = s.network.partitions[0]
    cut = ds.t[ds.partitioned]
    assert len(cut) > 0 and ((cut >= p.start_s) & (cut < p.end_s)).all()
    # r1 and r2 broadcast to each other every tick of the window: every one of those is cut
    ticks = round((p.end_s - p.start_s) / s.run.dt)
    assert len(cut) == 2 * ticks


def test_animation_is_written_with_a_progress_bar(tmp_path, recorded, capsys):
    _, log = recorded("e5.4-")
    view = load_run(log)
    f = animate_run(view, tmp_path, frames=6, fps=5, progress=True)
    assert f.exists() and f.stat().st_size > 1000 and f.suffix in (".gif", ".mp4")
    assert "6/6 frames" in capsys.readouterr().err
    assert "snapshots" in applicable(view)


def test_copath_plot_command(tmp_path, recorded, capsys):
    from orchestrator.cli import main

    _, log = recorded("e5.4-")
    assert main(["plot", str(log), "--out", str(tmp_path / "figs")]) == 0
    printed = capsys.readouterr().out.split()
    assert str(tmp_path / "figs" / "snapshots.png") in printed and (tmp_path / "figs" / "coordination.png").exists()
    assert main(["plot", str(tmp_path / "missing.mcap")]) == 2
    assert "missing.mcap" in capsys.readouterr().err
