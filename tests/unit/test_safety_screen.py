"""The far-neighbour screen of the safety filter's pass-through test (docs/reference/safety.md,
"The far-neighbour screen"): with bounds instead of discs for the neighbours whose rows cannot be
active, the test gives what the test on every disc gives (pass or not, and the same smallest
barrier), so the guard returns what it returned without the screen, on random cases and on the
calls of recorded runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath import safety
from copath.models import OmniModel, UnicycleModel
from copath.safety import GuardConfig, SafetyConfig, SafetyGuard

CONFIGS = {
    "plain": SafetyConfig(enabled=True),
    "commit": SafetyConfig(enabled=True, commit_accel_mps2=0.1, commit_speed_mps=0.02),
    "accel": SafetyConfig(enabled=True, accel_max_mps2=0.5),
    "centre-only": SafetyConfig(enabled=True, braking=False, lookahead_m=0.0, speed_max_mps=0.4),
}
OWN = {"unicycle a_max": UnicycleModel(a_max=1.0, alpha_max=1.0), "unicycle": UnicycleModel(),
       "omni": OmniModel()}
OTHERS = [UnicycleModel(a_max=1.0, alpha_max=1.0), UnicycleModel(a_max=0.3), UnicycleModel(), OmniModel()]


def _guard(cfg: SafetyConfig, own, n: int) -> SafetyGuard:
    models = {"a": own, **{f"n{k}": OTHERS[k % len(OTHERS)] for k in range(n)}}
    return SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.05 if isinstance(own, OmniModel) else 0.1))


def _feed(guards: list[SafetyGuard], rng, now: float, spread_m: float, n: int) -> None:
    """The same messages to every guard: neighbours from 0.2 m to ``spread_m`` away, of every age,
    with and without a velocity, some of them twice (an acceleration extrapolation)."""
    for k in range(n):
        if rng.random() < 0.15:
            continue  # not heard this time
        d, a = float(rng.uniform(0.2, spread_m)), float(rng.uniform(-math.pi, math.pi))
        pos = (d * math.cos(a), d * math.sin(a))
        stamp = now - float(rng.choice([0.0, 0.1, 0.3, 1.0, 1.9, 2.6]))
        vel = None if rng.random() < 0.2 else (float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.5, 0.5)),
                                              float(rng.choice([0.0, rng.uniform(-1, 1)])))
        twice = rng.random() < 0.3
        for g in guards:
            if twice:
                g.hear(f"n{k}", (pos[0] - 0.03, pos[1]), stamp - 0.1, vel)
            g.hear(f"n{k}", pos, stamp, vel)


def _command(own, rng) -> np.ndarray:
    return rng.uniform(-0.6, 0.6, 3) if isinstance(own, OmniModel) else np.r_[rng.uniform(-0.6, 0.6), rng.uniform(-1.2, 1.2)]


@pytest.mark.parametrize("own", list(OWN.values()), ids=list(OWN))
@pytest.mark.parametrize("cfg", list(CONFIGS.values()), ids=list(CONFIGS))
def test_screened_pass_through_is_the_test_on_every_disc(own, cfg):
    """Random guards: the screened test's answer is the one of :meth:`SafetyFilter._clear` on
    every disc (same None, same smallest barrier), and the screen skips discs, among them the
    one with the smallest barrier at times."""
    rng = np.random.default_rng(5)
    counts = {"pass": 0, "blocked": 0, "discs": 0, "made": 0, "min from a skipped disc": 0}
    for case in range(150):
        n = int(rng.integers(1, 16))
        g = _guard(cfg, own, n)
        now = 10.0
        _feed([g], rng, now, float(rng.choice([1.0, 3.0, 12.0])), n)
        if case % 7 == 0 and g._heard:
            g._note_lost([sorted(g._heard)[0]], now - 0.5)  # a robot held still: a disc the screen always computes
        pose = np.array([0.0, 0.0, float(rng.uniform(-math.pi, math.pi))])
        u_sat = g.filter._saturated(_command(own, rng))[1]
        want = g.filter._clear(pose, g.neighbours(now), None, None, (), u_sat)
        made = []
        disc = g._neighbour
        g._neighbour = lambda name, t: made.append(name) or disc(name, t)
        got = g._pass_through(now, pose, u_sat, ())
        assert got == want
        counts["pass" if want is not None else "blocked"] += 1
        counts["discs"] += len(g._heard)
        counts["made"] += len(made)
        # every robot heard far: its smallest barrier is one the first pass skipped, computed after it
        counts["min from a skipped disc"] += int(want is not None and want < math.inf and len(g._heard) >= 3
                                                 and len(made) <= 1 and not g._lost_at)
    assert counts["pass"] > 20 and counts["blocked"] > 10, counts
    assert counts["made"] < 0.75 * counts["discs"] and counts["min from a skipped disc"] > 2, counts


@pytest.mark.parametrize("own", list(OWN.values()), ids=list(OWN))
@pytest.mark.parametrize("cfg", [CONFIGS["commit"], CONFIGS["accel"], CONFIGS["plain"]], ids=["commit", "accel", "plain"])
def test_guard_with_the_screen_returns_what_it_returned_without(own, cfg):
    """Two guards fed the same messages, plans and commands over a run of steps, one with the
    screen and one without (every disc through the filter's own test): the same results, bit
    for bit, and the same counters."""
    rng = np.random.default_rng(9)
    n = 12
    screened, plain = _guard(cfg, own, n), _guard(cfg, own, n)
    plain._pass_through = lambda *a, **k: None  # noqa: ARG005  (the guard's path before the screen)
    dt = screened._dt
    x, y, th = 0.0, 0.0, 0.3
    active = 0
    command0 = _command(own, rng)
    for step in range(300):
        now = step * dt
        if step % 5 == 0:
            _feed([screened, plain], rng, now, float(rng.choice([0.8, 2.0, 6.0])), n)
        # a smooth nominal (kept plans are followed) with a jump now and then
        command = _command(own, rng) if step % 40 == 0 else np.r_[0.3, 0.1 * math.sin(step / 20.0), 0.0][:len(command0)]
        pose = np.array([x, y, th])
        a, b = screened.apply(pose, command, now), plain.apply(pose, command, now)
        assert np.array_equal(a.command, b.command)
        assert (a.active, a.change, a.slack, a.min_barrier, a.ok, a.biased) == (
            b.active, b.change, b.slack, b.min_barrier, b.ok, b.biased)
        active += a.active
        u = a.command
        vel = ((u[0] * math.cos(th) - u[1] * math.sin(th), u[0] * math.sin(th) + u[1] * math.cos(th), u[2])
               if len(u) == 3 else (u[0] * math.cos(th), u[0] * math.sin(th), u[1]))
        for g in (screened, plain):
            g.published(now, (x, y), vel)
        x, y, th = x + vel[0] * dt, y + vel[1] * dt, th + vel[2] * dt
    assert screened.counters() == plain.counters()
    assert len(screened._heard) >= safety.SCREEN_MIN_HEARD  # the screen was in use
    assert active > 10 and 300 - active >= 5  # both paths: filtered, and passed through


@pytest.mark.parametrize("robots,duration", [(6, 20.0), (16, 8.0)])
def test_screen_decides_as_every_disc_on_the_calls_of_a_recorded_run(monkeypatch, robots, duration):
    """E5.4 (6 robots) and E5.4 grown to 16 (``copath bench peers``) in one process: at every
    call, the screened test answers as the test on every disc."""
    from orchestrator import api
    from orchestrator.run.inprocess import run_scenario
    from orchestrator.studies.bench.peers import copath_scenario

    seen = {"calls": 0, "heard": 0, "made": 0}
    screened, disc = SafetyGuard._pass_through, SafetyGuard._neighbour

    def counted(self, name, now):
        seen["made"] += 1
        return disc(self, name, now)

    def checked(self, now, pose, u, tubes):
        got = screened(self, now, pose, u, tubes)
        made = seen["made"]
        assert got == self.filter._clear(pose, self.neighbours(now), None, None, tubes, u)
        seen["made"] = made
        seen["calls"] += 1
        seen["heard"] += len(self._heard)
        return got

    monkeypatch.setattr(SafetyGuard, "_neighbour", counted)
    monkeypatch.setattr(safety, "SCREEN_MIN_HEARD", 0)  # E5.4's five heard robots too
    monkeypatch.setattr(SafetyGuard, "_pass_through", checked)
    sc = api.load(copath_scenario(robots, False), [f"run.duration_s={duration}", f"run.settle_s={duration / 2}"])
    run_scenario(sc)
    assert seen["calls"] >= 0.9 * robots * duration / sc.run.dt
    assert seen["made"] < 0.5 * seen["heard"], seen  # most discs skipped
