"""The safety filter in closed loop (one process, ``run_scenario``): robots that collide
without it are kept apart with it, with every controller family's command left unchanged
when nobody is close (docs/reference/safety.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.control import Outgoing, StepResult
from copath.scenario import load_scenario, parse_scenario
from copath.wire.messages import Stats
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config

FAULTS = {"delay_ms": 100.0, "loss": 0.2}


def _five(on: bool, network=None, duration=20.0):
    s = load_scenario(config("e5.2-dmpc-five-robots"))
    over = {"safety": {"enabled": on}, "controller": {"jit": False}}
    if network:
        over["network"] = network
    return run_scenario(s.with_overrides(**over), duration_s=duration).metrics


def _interventions(m) -> int:
    return sum(r["safety_interventions"] or 0 for r in m["robots"].values())


@pytest.mark.long  # tier: README "Test tiers"
def test_five_robot_dmpc_collides_without_the_filter_and_not_with_it():
    off, on = _five(False), _five(True)
    assert off["fleet"]["collisions"] >= 1  # the start really is dangerous
    assert on["fleet"]["collisions"] == 0
    assert on["fleet"]["min_separation_m"] >= 0.4  # two omni discs of 0.2 m
    assert _interventions(on) > 0 and _interventions(off) == 0
    # the formation is still reached: coordination after settle_s within the scenario's target
    # (0.15 m) and within 2 cm of the run without the filter
    assert on["fleet"]["coordination_error_max_m"] <= 0.15
    assert on["fleet"]["coordination_error_max_m"] <= off["fleet"]["coordination_error_max_m"] + 0.02
    for r in on["robots"].values():
        assert r["limit_violations"] == 0  # the filtered command respects the wheel limits
        assert r["safety_ms_p50"] is not None  # timed: its speed is benchmarked (orchestrator/studies/bench/safety.py)


@pytest.mark.slow
def test_five_robot_dmpc_with_delay_and_loss_keeps_apart():
    on = _five(True, FAULTS)
    assert on["fleet"]["collisions"] == 0
    assert on["fleet"]["messages_dropped_by_faults"] > 0
    assert on["fleet"]["coordination_error_max_m"] <= 0.3


@pytest.mark.parametrize("network", [pytest.param(None, marks=pytest.mark.long),
                                     pytest.param(FAULTS, marks=pytest.mark.faults)])
def test_twelve_unicycles_swap_places_across_a_circle_without_colliding(network):
    s = load_scenario(config("e5.6-circle-swap"))
    over = {"network": network} if network else {}
    off = run_scenario(s.with_overrides(safety={"enabled": False}, **over), duration_s=10.0).metrics
    on = run_scenario(s.with_overrides(**over)).metrics
    assert off["fleet"]["collisions"] >= 12  # all twelve meet at the centre
    assert on["fleet"]["collisions"] == 0
    assert on["fleet"]["min_separation_m"] >= 0.12
    # the swap completes: steering round each other (look-ahead point, right-hand rule),
    # every robot reaches the start of the robot opposite it (s = 3 m) within the run
    assert all(r["path_progress_m"] >= 3.0 for r in on["robots"].values())
    assert all(r["safety_interventions"] > 0 for r in on["robots"].values())
    assert all(r["limit_violations"] == 0 for r in on["robots"].values())


@pytest.mark.long  # tier: README "Test tiers"
def test_circle_swap_without_the_deadlock_rule_is_safe_and_stall_detours_unwind_most_of_the_ring():
    # the same filter with the right-hand rule off: safe. The robots stop round the centre, and
    # with detours turned on the runtime's stall rule (on where the filter's rule is off;
    # docs/reference/detours.md) takes over:
    # every robot detours, 8 of the 12 get past the centre within 25 s; a symmetric jam of four
    # stays (docs/reference/detours.md, "What it cannot do")
    s = load_scenario(config("e5.6-circle-swap"))
    m = run_scenario(s.with_overrides(safety={"enabled": True, "deadlock_turn_rad": 0.0, "detours": True}), duration_s=25.0).metrics
    assert m["fleet"]["collisions"] == 0
    assert all(r["detours"] >= 1 and r["stalled_s"] > 4.0 for r in m["robots"].values())
    assert sum(r["path_progress_m"] > 2.0 for r in m["robots"].values()) >= 8  # past the centre (1.5 m)


# -- user controllers, unchanged: drive straight along the heading at 0.5 m/s -------------

class _Straight:
    talk = False

    def __init__(self, ctx) -> None:
        self.omni = ctx.model.kind == "omni"

    def step(self, obs, inbox):
        cmd = [0.5, 0.0, 0.0] if self.omni else [0.5, 0.0]
        out = [Outgoing("follower_status", {"tracking_error": 0.0})] if self.talk else []
        return StepResult(np.array(cmd), out, {})


class _TalkingStraight(_Straight):
    talk = True


def build_silent(ctx):
    return _Straight(ctx)


def build_talking(ctx):
    return _TalkingStraight(ctx)


def _head_on(model, builder, safety, sensors=None, n=2, network=None, records=False):
    robots = []
    for i in range(n):  # n robots on a circle of radius 1 m, all facing its centre
        a = 2 * math.pi * i / n
        robots.append({"name": f"r{i + 1}", "model": model, "pose": [math.cos(a), math.sin(a), a + math.pi]})
    raw = {"id": "head-on", "run": {"duration_s": 6.0, "dt": 0.1},
           "controller": {"type": f"tests.closed_loop.test_safety:{builder}"},
           "robots": robots, "safety": safety, "sensors": sensors or {}, "network": network or {}}
    res = run_scenario(parse_scenario(raw))
    return (res.metrics, _stats(res)) if records else res.metrics


def _stats(res) -> dict[str, dict]:
    """Closing counters of every robot (the ``stats`` records)."""
    return {r.proc: r.counters for _, _, r in res.records if isinstance(r, Stats) and r.proc != "sim"}


@pytest.mark.parametrize("model", ["omni", "unicycle"])
def test_user_controller_robots_driving_head_on_are_kept_apart(model):
    off = _head_on(model, "build_talking", {"enabled": False}, n=4)
    assert off["fleet"]["collisions"] >= 1
    # robots with no graph: the position in every broadcast envelope is overheard
    on = _head_on(model, "build_talking", {"enabled": True}, n=4)
    assert on["fleet"]["collisions"] == 0
    assert all(r["safety_interventions"] > 0 for r in on["robots"].values())


def test_silent_user_controller_is_kept_apart_by_range_readings():
    # a controller that sends nothing is never heard; the sensor ring still sees the others
    sensors = {"enabled": True, "count": 12, "max_range_m": 0.5}
    off = _head_on("unicycle", "build_silent", {"enabled": False}, sensors)
    assert off["fleet"]["collisions"] >= 1
    on = _head_on("unicycle", "build_silent", {"enabled": True}, sensors)
    assert on["fleet"]["collisions"] == 0


def test_formation_switching_without_its_repulsion_is_kept_apart_by_the_filter():
    # E6.6 with robots 1 and 3 swapping sides head-on and the controller's repulsive shaping
    # switched off (tests/closed_loop/test_ch6.py shows they collide without the filter)
    raw = dict(load_scenario(config("e6.6-")).raw)
    raw["controller"] = {**raw["controller"], "switch_at": [3.0], "k_r": 1e-9}
    slots = ([[0.0, 0.5], [0.0, -0.5]], [[0.0, 0.0], [0.8, 0.0]], [[0.0, -0.5], [0.0, 0.5]])
    raw["robots"] = [{**r, "controller": {**r.get("controller", {}), "slots": sl}}
                     for r, sl in zip(raw["robots"], slots)]
    m = run_scenario(parse_scenario({**raw, "safety": {"enabled": True}})).metrics
    assert m["fleet"]["collisions"] == 0 and m["fleet"]["min_separation_m"] >= 0.12
    assert sum(r["safety_interventions"] for r in m["robots"].values()) > 0


@pytest.mark.faults  # tier: README "Test tiers"
def test_column_at_one_second_delay_and_half_lost_with_the_filter_on():
    # issue 14's goal with the bundled [safety] on: E5.5's robots declare acceleration limits
    # (enforced by the simulator), send their velocity and commit to a tube round the arc it
    # predicts, so the filter bounds a stale neighbour by that tube instead of inflating it by
    # v_max tau; below 0.1 m with the braking-distance rows (docs/reference/safety.md, "Committed plans")
    s = load_scenario(config("e5.5-column"))
    assert s.safety.enabled and s.safety.braking and all(r.model.a_max is not None for r in s.robots)
    assert s.safety.commit_accel_mps2 is not None
    res = run_scenario(s.with_overrides(network={"delay_ms": 1000.0, "loss": 0.5}))
    m = res.metrics
    assert m["fleet"]["collisions"] == 0
    assert m["fleet"]["messages_dropped_by_faults"] > 0
    assert _interventions(m) > 0  # the filter did act on stale neighbours
    assert m["fleet"]["coordination_error_max_m"] < 0.1
    for r in m["robots"].values():
        assert r["limit_violations"] == 0
    assert all(c["safety_commit_breaks"] == 0 for c in _stats(res).values())


@pytest.mark.parametrize("model, n", [({"type": "omni", "a_max": 0.3, "alpha_max": 1.0}, 2),
                                      ({"type": "unicycle", "a_max": 0.3, "alpha_max": 1.0}, 2),
                                      ({"type": "unicycle", "a_max": 0.3, "alpha_max": 1.0}, 4)])
def test_robots_that_cannot_stop_at_once_are_still_kept_apart(model, n):
    # the simulator enforces the acceleration limit, so a filtered command is reached only
    # gradually; the braking-distance rows keep each robot's closing speed one it can shed in time
    off = _head_on(model, "build_talking", {"enabled": False}, n=n)
    assert off["fleet"]["collisions"] >= 1
    first_order = _head_on(model, "build_talking", {"enabled": True, "braking": False}, n=n)
    assert first_order["fleet"]["collisions"] >= 1  # a first-order barrier brakes too late
    on = _head_on(model, "build_talking", {"enabled": True}, n=n)
    assert on["fleet"]["collisions"] == 0
    assert all(r["safety_interventions"] > 0 for r in on["robots"].values())


COMMIT = {"enabled": True, "commit_accel_mps2": 0.1}


@pytest.mark.faults  # tier: README "Test tiers"
@pytest.mark.parametrize("model, n", [({"type": "omni", "a_max": 0.3, "alpha_max": 1.0}, 2),
                                      ({"type": "unicycle", "a_max": 0.3, "alpha_max": 1.0}, 4)])
def test_committed_plans_keep_robots_driving_head_on_apart_under_delay_and_loss(model, n):
    # each robot keeps within the tube round the arcs it published and keeps out of its
    # neighbours' tubes with their velocity known; robots driving straight at each other have
    # plans that meet, so they give up their promises (counted) to keep their centre rows, and
    # none collides at 500 ms of delay and 30 % loss (docs/reference/safety.md, "Committed plans")
    net = {"delay_ms": 500.0, "loss": 0.3}
    off = _head_on(model, "build_talking", {"enabled": False}, n=n, network=net)
    assert off["fleet"]["collisions"] >= 1
    m, stats = _head_on(model, "build_talking", COMMIT, n=n, network=net, records=True)
    assert m["fleet"]["collisions"] == 0
    assert all(r["safety_interventions"] > 0 for r in m["robots"].values())
    assert stats and all("safety_commit_breaks" in c for c in stats.values())


@pytest.mark.faults  # tier: README "Test tiers"
def test_six_robots_coordinate_at_one_second_delay_and_half_lost_with_committed_plans():
    # issue 14's goal with the bundled [safety] on (committed plans): E5.4's chain of six at
    # 1000 ms / 50 %, seed 1, below 0.1 m after settling, no collision, no promise broken
    s = load_scenario(config("e5.4-six-robots"))
    assert s.safety.enabled and s.safety.commit_accel_mps2 is not None
    res = run_scenario(s.with_overrides(network={"delay_ms": 1000.0, "loss": 0.5}))
    m = res.metrics
    assert m["fleet"]["collisions"] == 0
    assert m["fleet"]["messages_dropped_by_faults"] > 0
    assert _interventions(m) > 0
    assert m["fleet"]["coordination_error_max_m"] < 0.1
    assert all(c["safety_commit_breaks"] == 0 for c in _stats(res).values())


def test_a_committed_neighbour_is_a_small_disc_on_its_arc_and_the_promise_is_validated():
    from copath.config import ConfigError
    from copath.models import UnicycleModel
    from copath.safety import GuardConfig, SafetyConfig, SafetyGuard, commit_radius, predict_position

    with pytest.raises(ConfigError, match=r"safety.commit_accel_mps2 = -0.1 is not allowed"):
        SafetyConfig(enabled=True, commit_accel_mps2=-0.1)
    cfg = SafetyConfig(enabled=True, commit_accel_mps2=0.1)
    models = {n: UnicycleModel(a_max=0.3, alpha_max=1.0) for n in ("a", "b")}
    guard = SafetyGuard(GuardConfig(safety=cfg, name="a", models=models, dt=0.1))
    vel = (0.2, 0.0, 0.1)
    guard.hear("b", (1.0, 0.0), 0.0, vel)
    for age in (0.5, 1.5, 2.4):
        (nb,) = guard.neighbours(age)
        assert nb.spread == pytest.approx(commit_radius(cfg, age))
        assert nb.position == pytest.approx(predict_position((1.0, 0.0), vel, age))
        assert nb.committed is not None
    (nb,) = guard.neighbours(2.6)  # beyond the horizon: the acceleration-limit bound only
    assert nb.committed is None and (nb.spread is None or nb.spread > commit_radius(cfg, 2.6))
    # the sender side: a robot that published a plan and then stopped has left its tube
    guard.published(0.0, (0.0, 0.0, 0.0), vel)
    guard.apply((0.0, 0.0, 0.0), [0.0, 0.0], 2.0)
    assert guard.counters()["safety_commit_breaks"] == 1


def test_a_lost_robot_held_still_is_a_static_disc_passed_and_not_forgotten():
    """Robot b sends its position and velocity (0.4 m/s along x) up to t = 1 s, then its
    liveliness goes: the simulator holds it where it is then (it drove on with its last command
    for one period). Robot a drives at it along x at 0.5 m/s, 0.1 m off its line, from 1 s to
    9 s, long after ``max_age_s``: the filter keeps b as a static disc around where it may have
    stopped (SafetyGuard._held; docs/reference/safety.md, "A lost robot"), so a goes round it without
    touching it, and comes close. Before, b was forgotten after max_age_s and a drove into it."""
    from copath.models import OmniModel, integrate_body_velocity
    from copath.safety import GuardConfig, SafetyConfig, SafetyGuard

    dt = 0.1
    model = OmniModel()  # E5.1's robots
    models = {"a": model, "b": model}
    r = model.radius
    guard = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True, accel_max_mps2=1.5), name="a", models=models,
                                    dt=dt))
    vel_b = (0.4, 0.0, 0.0)
    for k in range(11):  # b's messages, t = 0 .. 1 s
        guard.hear("b", (0.4 * k * dt, 0.0), k * dt, vel_b)
    b_held = np.array([0.4 * 1.1, 0.0])  # it applied its last command for one more period
    pose = np.array([-1.5, 0.1, 0.0])
    nominal = [0.5, 0.0, 0.0]
    gaps, lost = [], frozenset({"b"})
    for k in range(11, 91):  # t = 1.1 .. 9 s: a learns of the loss at its first step after it
        res = guard.apply(pose, nominal, k * dt, lost=lost)
        pose = np.asarray(integrate_body_velocity(pose, np.asarray(res.command, dtype=float), dt), dtype=float)
        gaps.append(float(np.hypot(*(pose[:2] - b_held))))
        if k * dt == pytest.approx(3.2):
            (nb,) = guard.neighbours(k * dt)  # 2.2 s after its last message: still there, at rest
            assert nb.committed == (0.0, 0.0, 0.0, 0.0)
            assert np.hypot(*(np.asarray(nb.position) - b_held)) + r < nb.radius  # it holds b's disc
            held = nb
    gaps = np.array(gaps)
    assert gaps.min() >= 2 * r + 0.01  # the footprints and the margin
    # it really passed close: the held disc is b's footprint grown by half the 0.08 m it may
    # have driven on (0.2 s at 0.4 m/s) and the extrapolation's 0.09 m spread at 0.2 s
    assert gaps.min() < 2 * r + 0.01 + 0.04 + 0.09 + 0.02
    assert pose[0] > b_held[0] + 0.2 and gaps[-1] > gaps.min() + 0.1  # and went on past it
    # back (a restarted process) but not heard yet: b may drive again, the held disc growing at
    # its speed bound; where in it b stopped is the disc's spread (its directions are unknown)
    guard.apply(pose, nominal, 9.1, lost=frozenset())
    (nb,) = guard.neighbours(9.3)
    assert nb.committed is None and not nb.held and nb.radius == model.radius
    assert nb.position == pytest.approx(held.position)
    assert nb.spread == pytest.approx(held.radius - r + nb.speed_max * (0.2 + dt))
    # heard with a new stamp: an ordinary neighbour again
    guard.hear("b", (0.5, 0.0), 9.2, (0.0, 0.0, 0.0))
    guard.apply(pose, nominal, 9.3, lost=frozenset())
    (nb,) = guard.neighbours(9.3)
    assert nb.position == pytest.approx((0.5, 0.0)) and nb.radius == model.radius


def test_a_robot_back_from_a_hold_grows_from_rest_at_its_acceleration_limit():
    """A restarted robot with an enforced ``a_max`` was held at zero command (braking from at
    most v_hold inside its held disc): once back it can be within v_hold t + a_max t^2 / 2 of
    that disc after t, not its speed bound times t (docs/reference/safety.md, "A lost robot"),
    so the disc a neighbour keeps off does not jump at the return (DMPC triangle, realtime chaos
    soak: 0.388 m against 0.40 m of footprints 0.07 s after a restart)."""
    from copath.models import OmniModel
    from copath.safety import GuardConfig, SafetyConfig, SafetyGuard

    dt = 0.05
    model = OmniModel(a_max=1.0, alpha_max=3.0)  # E5.2's robots
    guard = SafetyGuard(GuardConfig(safety=SafetyConfig(enabled=True), name="a", models={"a": model, "b": model},
                                    dt=dt))
    for k in range(21):  # b at 0.4 m/s along x up to t = 1 s, then killed
        guard.hear("b", (0.4 * k * dt, 0.0), k * dt, (0.4, 0.0, 0.0))
    pose = np.array([0.0, 1.0, 0.0])
    guard.apply(pose, [0.0, 0.0, 0.0], 1.05, lost=frozenset({"b"}))
    (held,) = guard.neighbours(1.05)
    assert held.held and held.spread == 0.0
    guard.apply(pose, [0.0, 0.0, 0.0], 2.0, lost=frozenset())  # its token is back at 2 s
    for since in (0.0, 0.1, 0.5):
        (nb,) = guard.neighbours(2.0 + since)
        # its speed at the hold: the sent 0.4 m/s plus a_max over the hold's age (0.1 s) and a period
        v_hold = min(nb.speed_max, 0.4 + model.a_max * (0.1 + dt))
        t = since + dt
        moved = min(nb.speed_max * t, v_hold * t + 0.5 * model.a_max * t**2)
        assert nb.position == pytest.approx(held.position) and nb.radius == model.radius
        assert nb.spread == pytest.approx(held.radius - model.radius + moved)
        assert nb.spread < held.radius - model.radius + nb.speed_max * t  # tighter than its speed bound
