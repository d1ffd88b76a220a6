"""``copath envelope`` (orchestrator/studies/envelope.py) and the delay-robust coupling of the
Sec. 5.5 law (agent/controllers/consensus/controller.py: prediction over the message age, gains
scheduled on the age of information)."""

from __future__ import annotations

import csv
import math

import pytest

from agent.controllers.consensus.controller import age_weight, neighbour_states
from copath.config import ConfigError
from copath.control import PeerMessage
from copath.control.inbox import Received
from orchestrator.studies import envelope, sweep
from orchestrator.cli import main as copath


# --- grid and cells ---

def test_cells_and_grid_parse_and_reject_with_the_key_named():
    assert envelope.parse_cells("0/0,300/0.3, 1000/0.5") == [(0.0, 0.0), (300.0, 0.3), (1000.0, 0.5)]
    assert envelope.grid([0, 500], [0, 0.5]) == [(0, 0), (0, 0.5), (500, 0), (500, 0.5)]
    for bad in ("300", "300/1.5", "-1/0", "a/b"):
        with pytest.raises(ConfigError, match="--cells"):
            envelope.parse_cells(bad)
    with pytest.raises(ConfigError, match="--delays"):
        envelope.parse_numbers("0,-100", "--delays")
    with pytest.raises(ConfigError, match="--losses"):
        envelope.grid([0], [1.5])


def _row(i, d, p, seed, figures, met=3, total=3, ok=True):
    return sweep.SweepRow(i, {"network.delay_ms": d, "network.loss": p, "run.seed": seed}, f"r{i}", ok,
                          None if ok else "x", figures, met, total, 0.1)


def test_cells_take_mean_and_worst_over_seeds_in_the_metrics_sense():
    rows = [_row(0, 0, 0, 1, {"coordination_error_max_m": 0.01}),
            _row(1, 0, 0, 2, {"coordination_error_max_m": 0.03}, met=2),
            _row(2, 500, 0.5, 1, {"tasks_completed": 3.0}),
            _row(3, 500, 0.5, 2, {"tasks_completed": 1.0})]
    coord = {(c.delay_ms, c.loss): c for c in envelope.cells_of(rows[:2], "coordination_error_max_m", 0.02)}
    c = coord[(0.0, 0.0)]
    assert (c.runs, c.mean, c.worst, c.met, c.targets_met, c.targets_total) == (2, pytest.approx(0.02), 0.03,
                                                                                False, 5, 6)
    assert not c.all_met
    tasks = envelope.cells_of(rows[2:], "tasks_completed", 3)[0]
    assert (tasks.worst, tasks.mean, tasks.met) == (1.0, 2.0, False)  # at least: the worst is the smallest
    text = envelope.format_envelope([c, tasks], "coordination_error_max_m")
    assert "missed (0.02)" in text and "0.02/0.03" in text


def test_headline_metric_follows_the_targets():
    from orchestrator import api

    assert envelope.headline_metric(api.load("e6.5-roles-six-robots-x")) == "tasks_completed"
    assert envelope.headline_metric(api.load("e5.5-column-lemniscate")) == "coordination_error_max_m"


def test_copath_envelope_writes_the_table_and_the_heat_map(tmp_path, capsys):
    out = tmp_path / "env"
    rc = copath(["envelope", "e5.5-column-lemniscate", "--cells", "0/0,300/0.3", "--seeds", "1", "--inprocess",
                 "-j", "1", "-q", "--set", "run.duration_s=4", "--set", "run.settle_s=2", "--out", str(out)])
    assert rc == 0
    with (out / "envelope.csv").open() as fh:
        cells = list(csv.DictReader(fh))
    assert [(float(c["delay_ms"]), float(c["loss"])) for c in cells] == [(0.0, 0.0), (300.0, 0.3)]
    assert all(c["metric"] == "coordination_error_max_m" and float(c["worst"]) >= 0 for c in cells)
    with (out / "runs.csv").open() as fh:
        assert len(list(csv.DictReader(fh))) == 2
    png = out / "envelope-coordination_error_max_m.png"
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"
    assert "coordination_error_max_m mean/worst" in capsys.readouterr().out


def test_copath_envelope_rejects_a_swept_network_key(tmp_path, capsys):
    rc = copath(["envelope", "e5.5-column-lemniscate", "--cells", "0/0", "--seeds", "1", "--inprocess", "-q",
                 "--set", "network.loss=0.1", "--out", str(tmp_path / "x")])
    assert rc == 2
    assert "network.loss" in capsys.readouterr().err


# --- the delay-robust coupling ---

def test_age_weight_keeps_the_effective_delay_at_the_nominal_age():
    assert age_weight(0.1, 0.6) == 1.0 and age_weight(0.6, 0.6) == 1.0
    for age in (0.7, 1.0, 2.0):
        assert age_weight(age, 0.6) * age == pytest.approx(0.6)
        assert 0 < age_weight(age, 0.6) < 1


def _got(stamp, payload, t):
    return Received(PeerMessage(sender="r2", kind="coord_state", stamp=stamp, payload=payload, age=t - stamp), t)


def test_a_neighbour_is_predicted_exactly_under_constant_acceleration():
    s0, v0, a0, stamp, t = 3.0, 0.2, 0.05, 10.0, 11.0
    coord = lambda p: (p["s"], p["sdot"], p["s_d"], p["sddot"])  # noqa: E731
    got = _got(stamp, {"s": s0, "sdot": v0, "s_d": 0.5, "sddot": a0}, t)
    (n,) = neighbour_states([got], t, xi=0.0, coordinate=coord, age_nominal_s=0.6)
    assert n.xi == pytest.approx(s0 + v0 + 0.5 * a0 - 0.5)
    assert n.sdot == pytest.approx(v0 + a0)
    assert n.weight == pytest.approx(0.6)
    (m,) = neighbour_states([got], t, xi=0.0, coordinate=coord, predict_acceleration=False)
    assert m.xi == pytest.approx(s0 + v0 - 0.5) and m.weight == 1.0
    assert math.isclose(m.sdot, v0)


# --- (6.16) under delay ---

def _pi_decay_steps(delay_steps: int, rates: bool, dt: float = 0.1) -> int:
    """Steps until both robots of a pair, both finished (w = 0), have z <= 0.1."""
    from agent.controllers.roles.averaging import PIConsensus

    pis = [PIConsensus(k_z=0.5, k_p=8.0, k_i=4.0) for _ in range(2)]
    sent: list[list[tuple]] = [[], []]
    for k in range(2000):
        for i, pi in enumerate(pis):
            old = sent[1 - i][k - delay_steps] if k - delay_steps >= 0 else (1.0, 0.0, 1, 0.0, 0.0)
            z, eta, deg, zdot, etadot = old
            entry = (z, eta, deg, zdot, etadot, delay_steps * dt) if rates else (z, eta, deg)
            pi.step(0.0, [entry], dt)
        for i, pi in enumerate(pis):
            sent[i].append((pi.z, pi.eta, 1, pi.zdot, pi.etadot))
        if all(pi.z <= 0.1 for pi in pis):
            return k + 1
    return 2000


def test_task_sequencing_consensus_decays_at_its_own_rate_under_delay():
    undelayed = _pi_decay_steps(1, rates=False)
    plain = _pi_decay_steps(5, rates=False)
    predicted = _pi_decay_steps(5, rates=True)
    assert plain > 2 * undelayed  # the stale z_j holds the team back (docs/reference/envelope.md)
    assert predicted <= 1.3 * undelayed
