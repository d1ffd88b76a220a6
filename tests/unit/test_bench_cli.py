"""``copath bench``'s subcommand table (orchestrator/studies/bench/harness.py): the chaos soak
and the metrics comparison are subcommands, their arguments parsed and bad ones refused
with the argument, the value and what is allowed. Nothing here starts a run."""

from __future__ import annotations

import json

import pytest

from orchestrator.cli import main as copath
from orchestrator.studies.bench.chaos import KINDS
from orchestrator.studies.bench.harness import SUBCOMMANDS, parser


def test_chaos_arguments_parse_into_the_soak_settings():
    a = parser("chaos").parse_args(["--kinds", "kill, stop", "--minutes", "0.5", "--faults", "3", "--inprocess"])
    assert a.kinds == ("kill", "stop") and a.minutes == 0.5 and a.faults == 3 and a.inprocess
    d = parser("chaos").parse_args([])
    assert d.kinds == KINDS and d.minutes == 10.0 and d.faults == 40 and d.scenario == "e5.4-"


def test_chaos_takes_scenario_overrides_and_refuses_a_bad_one_naming_it(capsys):
    from orchestrator.studies.bench.chaos import prepare

    a = parser("chaos").parse_args(["--set", "run.cut_off=drive", "--set", "network.delay_ms=50"])
    assert a.set == ["run.cut_off=drive", "network.delay_ms=50"]
    scen, faults = prepare("e5.5-", "lockstep", "restart", 1.0, 3, 1, overrides=a.set)
    assert scen.run.cut_off == "drive" and scen.network.delay_ms == 50 and len(faults) == 3
    assert prepare("e5.5-", "lockstep", "restart", 1.0, 3, 1)[0].run.cut_off == "hold"  # the bundled rule
    assert copath(["bench", "chaos", "--scenario", "e5.5-", "--set", "run.cut_off=sideways", "--minutes", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "run.cut_off" in err and "'sideways'" in err and "drive" in err, err


def test_chaos_first_fault_comes_after_the_scenarios_settling_time_or_the_warmup_given(capsys):
    from orchestrator.studies.bench.chaos import MIN_WARMUP_S, prepare

    scen, faults = prepare("e5.4-six-robots-lemniscate", "lockstep", "restart", 10.0, 40, 1)
    assert scen.run.settle_s == 50.0 and min(f.t for f in faults) >= 50.0  # E5.4's transient
    assert max(f.t for f in faults) <= 600.0 - 15.0  # the tail before the end stays
    _, early = prepare("e5.4-six-robots-lemniscate", "lockstep", "restart", 10.0, 40, 1, warmup_s=0.0)
    assert min(f.t for f in early) < 10.0
    _, dmpc = prepare("e5.2-dmpc-ellipse-triangle", "lockstep", "restart", 10.0, 40, 1)
    assert min(f.t for f in dmpc) >= 15.0  # its settle_s
    a = parser("chaos").parse_args(["--warmup", "20"])
    assert a.warmup == 20.0 and parser("chaos").parse_args([]).warmup is None
    # a scenario that settles at once still waits MIN_WARMUP_S for its first fault
    _, quick = prepare("e5.5-", "lockstep", "restart", 10.0, 40, 1, overrides=["run.settle_s=0"])
    assert MIN_WARMUP_S <= min(f.t for f in quick) < MIN_WARMUP_S + 15.0
    with pytest.raises(ValueError, match="warmup_s = 700"):
        prepare("e5.5-", "lockstep", "restart", 10.0, 3, 1, warmup_s=700)
    with pytest.raises(ValueError, match=r"the warm-up \(the scenario's run.settle_s\) = 30 .* below the soak's 24 s"):
        prepare("e5.5-", "lockstep", "restart", 0.4, 3, 1)  # E5.5 settles at 30 s
    assert copath(["bench", "chaos", "--scenario", "e5.5-", "--minutes", "0.1", "--warmup", "30"]) == 2
    err = capsys.readouterr().err
    assert "warmup_s = 30" in err and "below the soak's 6 s" in err, err


@pytest.mark.parametrize("argv, words", [
    (["--kinds", "kill,bogus"], ("--kinds", "'bogus'", "allowed", "partition")),
    (["--minutes", "0"], ("--minutes", "'0'", "> 0")),
    (["--faults", "many"], ("--faults", "'many'", "number")),
    (["--policy", "fail"], ("--policy", "'fail'", "restart")),
    (["--warmup", "-1"], ("--warmup", "'-1'", ">= 0")),
])
def test_chaos_refuses_bad_arguments_naming_them(capsys, argv, words):
    with pytest.raises(SystemExit) as e:
        copath(["bench", "chaos", *argv])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert all(w in err for w in words), err


def _results(root, **metrics):
    for stem, m in metrics.items():
        (root / stem).mkdir(parents=True)
        (root / stem / "metrics.json").write_text(json.dumps(m))
    return root


def test_compare_metrics_ignores_timing_keys_and_reports_every_other_difference(tmp_path, capsys):
    before = _results(tmp_path / "a", s1={"ok": True, "wall_time_s": 1.0, "fleet": {"collisions": 0, "solve_ms_p99": 2.0}})
    same = _results(tmp_path / "b", s1={"ok": True, "wall_time_s": 9.0, "fleet": {"collisions": 0, "solve_ms_p99": 7.0}})
    other = _results(tmp_path / "c", s1={"ok": True, "wall_time_s": 1.0, "fleet": {"collisions": 2, "solve_ms_p99": 2.0}})
    assert copath(["bench", "compare-metrics", "compare", str(before), str(same)]) == 0
    assert copath(["bench", "compare-metrics", "compare", str(before), str(other)]) == 1
    out = capsys.readouterr().out
    assert "s1: fleet.collisions: 0 -> 2" in out and "1 differences" in out


def test_compare_metrics_refuses_what_it_cannot_read(tmp_path, capsys):
    assert copath(["bench", "compare-metrics", "compare", str(tmp_path / "none"), str(tmp_path)]) == 2
    assert "before = " in capsys.readouterr().err
    assert copath(["bench", "compare-metrics", "run", str(tmp_path / "out"), "--scenarios", "e9.9-nothing"]) == 2
    err = capsys.readouterr().err
    assert "--scenarios = 'e9.9-nothing' is not allowed" in err and not (tmp_path / "out").exists()


def test_every_subcommand_has_a_parser_and_an_unknown_one_is_refused(capsys):
    for what in SUBCOMMANDS:
        assert parser(what).prog == f"copath bench {what}"
    with pytest.raises(ValueError, match="allowed: solve"):
        parser("nope")
    with pytest.raises(SystemExit) as e:
        copath(["bench", "nope"])
    assert e.value.code == 2 and "compare-metrics" in capsys.readouterr().err
