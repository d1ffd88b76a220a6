"""The detour stage's geometry (copath/detour.py, docs/reference/detours.md), without a controller: a
robot is moved along its lane as shifted by the stage, as a perfect controller would."""

from __future__ import annotations

import math

import numpy as np
import pytest

from copath.detour import (DetourConfig, DetourPlanner, bump, plan_shift, polygon_disc, ray_discs, stretch_command,
                           turn_command)
from copath.paths import circle, line

DT = 0.1
R = 0.06  # a c't-Bot's footprint


def _box(cx: float, cy: float, half: float = 0.1):
    return [[cx - half, cy - half], [cx + half, cy - half], [cx + half, cy + half], [cx - half, cy + half]]


def _drive(planner: DetourPlanner, speed: float = 0.2, x0: float = 0.0, duration: float = 40.0, direction: int = 1,
           peers=(), ranges_of=None):
    """Move a robot along the straight path y = 0 at ``speed``, its true lateral position the
    stage's offset (a controller that keeps the pose it is shown on the path). Returns the
    true positions, the poses shown, the offsets and the events."""
    x, y = x0, 0.0
    heading = 0.0 if direction > 0 else math.pi
    out = {"true": [], "seen": [], "offset": [], "events": []}
    for k in range(int(duration / DT)):
        pose = np.array([x, y, heading])
        ranges = None if ranges_of is None else ranges_of(pose)
        step = planner.step(k * DT, pose, ranges, None if ranges is None else 2 * np.pi * np.arange(12) / 12,
                            peers)
        out["true"].append(pose)
        out["seen"].append(step.pose)
        out["offset"].append(step.offset)
        out["events"] += [(k * DT, what, d) for what, d in step.events]
        x += direction * speed * DT
        y = step.offset  # the controller keeps the shown pose on the path: the true one on the shifted lane
    return {k: (np.array(v) if k != "events" else v) for k, v in out.items()}


def test_bump_is_zero_outside_one_alongside_and_smooth():
    u = np.linspace(-1.0, 4.0, 5001)
    b = bump(u, 1.0, 2.0, 0.6, 0.7)
    assert np.all(b[u <= 0.4] == 0.0) and np.all(b[u >= 2.7] == 0.0)
    assert np.allclose(b[(u >= 1.0) & (u <= 2.0)], 1.0)
    assert np.all(np.diff(b[u <= 1.5]) >= -1e-12) and np.all(np.diff(b[u >= 1.5]) <= 1e-12)
    slope = np.diff(b) / np.diff(u)
    assert np.max(np.abs(slope)) < 1.875 / 0.6 + 1e-3  # the quintic's peak slope 15/8 per ramp length
    assert abs(slope[np.searchsorted(u, 0.401)]) < 1e-3 and abs(slope[np.searchsorted(u, 2.699)]) < 1e-3


def test_polygon_and_ray_discs():
    x, y, r = polygon_disc(_box(1.0, 2.0))
    assert (x, y) == pytest.approx((1.0, 2.0)) and r == pytest.approx(math.sqrt(2) * 0.1)
    angles = 2 * np.pi * np.arange(12) / 12
    ranges = np.full(12, np.inf)
    ranges[3] = 0.3  # the ray at 90 deg of a robot heading +x: a point 0.3 m beyond its rim, to its left
    (px, py, half), = ray_discs([1.0, 1.0, 0.0], ranges, angles, R, 0.5)
    assert (px, py) == pytest.approx((1.0, 1.0 + 0.3 + R))
    assert half == pytest.approx((0.3 + R) * math.sin(math.pi / 12))  # half the chord to the next ray


def test_plan_shift_clears_every_disc_by_the_width():
    left, right = plan_shift([0.05, -0.1], [0.1, 0.1], 0.13, 0.0)
    assert left == pytest.approx(0.05 + 0.23) and right == pytest.approx(-0.1 - 0.23)
    assert plan_shift([], [], 0.13, 0.0) == (0.0, 0.0)


@pytest.mark.parametrize("lateral, side", [(0.0, "right"), (0.04, "right"), (-0.04, "left")])
def test_known_box_detour_keeps_the_gap_and_rejoins(lateral, side):
    path = line((-1.0, 0.0), 0.0, 20.0)
    planner = DetourPlanner(path, R, True, DT, known=[(_box(3.0, lateral), (0.0, 0.0))])
    run = _drive(planner)
    p = run["true"]
    # the disc round the box is kept out of by the robot's radius, the margin and the clearance
    gap = np.hypot(p[:, 0] - 3.0, p[:, 1] - lateral) - polygon_disc(_box(3.0, lateral))[2] - R
    assert gap.min() >= planner.config.clearance_m + planner.config.margin_m - 0.01
    starts = [e for e in run["events"] if e[1] == "detour_start"]
    ends = [e for e in run["events"] if e[1] == "detour_end"]
    assert len(starts) == 1 and len(ends) == 1 and starts[0][2]["side"] == side
    assert (run["offset"].min() < 0) == (side == "right")
    # the pose shown is the true one moved back by the offset: on the path, up to the one step
    # by which this robot lags the offset; the true one is back on the path after the box
    assert np.allclose(run["seen"][:, 1], p[:, 1] - run["offset"], atol=1e-12)
    assert np.max(np.abs(run["seen"][:, 1])) < 0.03
    assert np.all(run["offset"][p[:, 0] > 4.5] == 0.0)
    # no jump: the lateral shift moves by at most the bump's slope times the distance per step
    assert np.max(np.abs(np.diff(run["offset"]))) < 0.2 * DT * 2.0


def test_nothing_near_leaves_the_pose_untouched():
    path = line((-1.0, 0.0), 0.0, 20.0)
    planner = DetourPlanner(path, R, True, DT, known=[(_box(30.0, 5.0), (0.0, 0.0))])
    pose = np.array([0.0, 0.01, 0.1])
    step = planner.step(0.0, pose)
    assert step.pose is pose and step.offset == 0.0 and not step.events and planner.s is None


def test_a_lane_blocked_wall_to_wall_is_not_detoured():
    path = line((-1.0, 0.0), 0.0, 20.0)
    walls = [(_box(3.0, y, 0.1), (0.0, 0.0)) for y in np.arange(-1.6, 1.61, 0.2)]
    planner = DetourPlanner(path, R, True, DT, known=walls, config=DetourConfig(max_offset_m=1.0))
    run = _drive(planner, duration=10.0)
    assert not run["events"] and np.all(run["offset"] == 0.0)


def test_held_robot_disc_is_a_block_and_live_one_is_not():
    path = line((-1.0, 0.0), 0.0, 20.0)
    held = DetourPlanner(path, R, True, DT)
    run = _drive(held, peers=[(3.0, 0.0, 0.2, True)])
    assert [e[2]["reason"] for e in run["events"] if e[1] == "detour_start"] == ["held"]
    live = DetourPlanner(path, R, True, DT)
    run = _drive(live, peers=[(3.0, 0.0, 0.2, False)], duration=10.0)  # a teammate ahead: no detour
    assert not run["events"]


def test_sensed_box_through_the_ring_and_teammates_filtered():
    from sim.geometry import ray_cast  # the simulator's rays (tests may use sim/)

    path = line((-1.0, 0.0), 0.0, 20.0)
    box = np.array(_box(3.0, 0.0))
    angles = 2 * np.pi * np.arange(12) / 12

    def ranges_of(pose):
        r = np.asarray(ray_cast(pose[:2], float(pose[2]), angles, 0.5 + R, [box]), dtype=float) - R
        return np.where(np.isfinite(r), np.clip(r, 0.0, 0.5), np.inf)

    planner = DetourPlanner(path, R, True, DT, sensor_max_range=0.5)
    run = _drive(planner, ranges_of=ranges_of)
    p = run["true"]
    assert [e[2]["reason"] for e in run["events"] if e[1] == "detour_start"] == ["sensed"]
    clear = np.array([_clearance(q, box) for q in p[:, :2]]) - R
    assert clear.min() > 0.0
    assert p[-1, 0] > 6.0 and abs(p[-1, 1]) < 1e-9  # past the box and back on the path
    # the same readings explained by a live teammate standing there are not an obstacle
    mate = DetourPlanner(path, R, True, DT, sensor_max_range=0.5)
    run = _drive(mate, ranges_of=ranges_of, peers=[(3.0, 0.0, 0.15, False)], duration=12.0)
    assert not run["events"]


def _clearance(p, poly) -> float:
    """Distance from a point to a convex polygon's boundary (positive outside)."""
    best = math.inf
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        ab, ap = b - a, p - a
        t = min(max(float(ap @ ab) / float(ab @ ab), 0.0), 1.0)
        best = min(best, float(np.hypot(*(ap - t * ab))))
    return best


def test_head_on_stall_both_keep_right_and_pass():
    """Two robots facing each other on one lane, each stopped by the other's disc (what the
    safety filter does): after stall_s each goes round the other on its own right."""
    path = line((-5.0, 0.0), 0.0, 20.0)
    a = DetourPlanner(path, R, True, DT)
    b = DetourPlanner(path, R, True, DT)
    pa, pb = np.array([0.0, 0.0, 0.0]), np.array([0.3, 0.0, math.pi])
    offs_a, offs_b, ev = [], [], []
    for k in range(200):
        t = k * DT
        sa = a.step(t, pa, peers=[(pb[0], pb[1], R, False)])
        sb = b.step(t, pb, peers=[(pa[0], pa[1], R, False)])
        ev += sa.events + sb.events
        offs_a.append(sa.offset)
        offs_b.append(sb.offset)
        if a.plan is not None and b.plan is not None:  # both detouring: they drive on
            pa = np.array([pa[0] + 0.2 * DT, sa.offset, 0.0])
            pb = np.array([pb[0] - 0.2 * DT, sb.offset, math.pi])
    starts = [d for what, d in ev if what == "detour_start"]
    assert len(starts) == 2 and all(d["reason"] == "stalled" and d["side"] == "right" for d in starts)
    assert min(offs_a) < 0 < max(offs_b)  # a (going +x) passes below, b (going -x) above
    assert pa[0] > 0.3 and pb[0] < 0.0  # they passed each other


def test_command_is_stretched_with_the_lane_round_a_bend():
    """On the outside of a bend the shifted lane is longer than the path: an omni robot's speed
    along the path is scaled by the ratio (1 - kappa (q + d)) / (1 - kappa q), so its path
    coordinate advances at the rate the controller set; a unicycle's command is left as it is
    (docs/reference/detours.md, "The method")."""
    path = circle(1.0)  # counter-clockwise: the left normal points to the centre, kappa = 1
    # a held disc just inside the path a quarter turn ahead: the outside (the robot's right) is nearer
    peers = [(0.0, 0.93, 0.2, True)]
    for unicycle in (False, True):
        planner = DetourPlanner(path, R, unicycle, DT)
        plateau, shifted, d = [], 0, 0.0
        for k in range(int(12.0 / DT)):
            x, y, th, _ = path.frame(0.2 * k * DT)
            pose = np.array([x - d * math.sin(th), y + d * math.cos(th), th])  # on the shifted lane
            step = planner.step(k * DT, pose, peers=peers)
            d = step.offset
            cmd = np.array([0.2, 0.0]) if unicycle else np.array([0.2, 0.0, 0.2])
            out = stretch_command(cmd, step.stretch)
            if step.offset == 0.0 or unicycle:
                assert out is cmd  # no shift, or a unicycle: the command is untouched
                shifted += step.offset != 0.0
            elif abs(planner.plan.slope(planner.s)) < 1e-9:
                plateau.append((step.offset, out))
        if unicycle:
            assert shifted > 0  # it did detour
            continue
        assert plateau, "the detour has a plateau alongside the disc"
        for d, out in plateau:
            assert d < 0.0  # the outside, the robot's right
            assert out[0] == pytest.approx(0.2 * (1.0 - d), rel=1e-9)
            assert out[1] == pytest.approx(0.0, abs=1e-9) and out[2] == 0.2  # turn rate untouched


def _column(first_detour: bool, duration: float = 80.0):
    """A robot that wants 0.25 m/s behind a teammate that goes 0.15 m/s on one lane (y = 0); the
    safety filter (modelled: the robot held to the teammate's speed within 0.35 m behind it,
    ``pressed``) holds it back. With ``first_detour`` a held robot's disc at x = 1.5 m is gone
    round first (a column whose order a kill inverted). Returns the robot's and the teammate's
    x at the end, the events and the smallest distance between them."""
    path = line((-1.0, 0.0), 0.0, 40.0)
    planner = DetourPlanner(path, R, True, DT)
    x, y, xt = 0.0, 0.0, 4.0
    held = [(1.5, 0.0, 0.15, True)] if first_detour else []
    events, closest = [], math.inf
    pressed = False
    for k in range(int(duration / DT)):
        step = planner.step(k * DT, np.array([x, y, 0.0]), peers=held + [(xt, 0.0, R, False)], pressed=pressed)
        events += [what if what != "detour_start" else d["reason"] for what, d in step.events]
        y = step.offset
        gap = xt - x
        pressed = 0.0 < gap < 0.35 and abs(y) < 2 * R + 0.05
        x += (0.15 if pressed else 0.25) * DT
        xt += 0.15 * DT
        closest = min(closest, math.hypot(xt - x, y))
    return x, xt, events, closest


def test_a_robot_held_back_behind_a_teammate_after_a_detour_passes_it():
    """A column whose order a detour inverted (docs/reference/detours.md, "Passing"): a robot
    that has detoured and that the filter keeps holding back behind a live teammate on its lane
    goes round it on its right, past it, and rejoins; a robot that never detoured stays behind
    (runs without obstacles or lost robots are left as they were)."""
    x, xt, events, closest = _column(first_detour=True)
    assert "passing" in events
    assert x > xt + 0.3  # past the teammate, back on its lane
    assert closest > 2 * R  # never touched it
    x, xt, events, _ = _column(first_detour=False)
    assert "passing" not in events and x < xt


def test_a_robot_stalled_at_a_block_sees_the_shift_at_once():
    """A held disc just ahead of a robot that stands still: the ramp of a detour begun where the
    robot stands is one it never enters (its controller would see no shift); a stalled robot's
    ramp lies behind it, so the pose it is shown is off its lane from the first step."""
    path = line((-1.0, 0.0), 0.0, 20.0)
    block = [(0.27, 0.02, 0.1, True)]
    pose = np.array([0.0, 0.0, 0.0])

    def shown(planner: DetourPlanner, t0: float) -> list[float]:
        return [planner.step(t0 + k * DT, pose, peers=block).offset for k in range(6)]

    stalled = DetourPlanner(path, R, True, DT)
    for k in range(45):  # 4.5 s without moving, nothing in sight: stalled
        stalled.step(k * DT, pose)
    assert stalled.stalled(4.4)
    offsets = shown(stalled, 4.5)
    assert stalled.plan is not None and stalled.plan.reason == "held"
    # where it stands the lane is already shifted by nearly the detour's whole height
    assert abs(offsets[0]) > 0.9 * abs(stalled.plan.target) > 0.1 and offsets[-1] == offsets[0]
    fresh = DetourPlanner(path, R, True, DT)  # just arrived: the ramp begins where it stands
    assert all(abs(o) < 1e-12 for o in shown(fresh, 0.0)) and fresh.plan is not None


def test_a_unicycle_in_a_column_turns_on_the_spot_before_a_steep_ramp_round_a_held_robot():
    """docs/reference/detours.md, "Turn first": a held disc met 0.5 m ahead gets the shortest ramp
    (0.25 m for about 0.35 m of shift, up to 70 degrees); a unicycle in a column, heading along
    its path, is told to turn on the spot towards the ramp's steepest heading and to stop turning
    once within 0.3925 rad of it; its controller is shown that heading as the lane's until the
    ramp is behind it. Not for a disc that is not held, nor for a robot on a path of its own
    (the default), nor for an omni robot, nor for one at the held disc's edge already, nor
    round a robot held because it is quiet."""
    path = line((-1.0, 0.0), 0.0, 20.0)
    block = [(0.55, 0.0, 0.2, True)]
    cfg = DetourConfig(turn_first=True)

    def first(planner, heading=0.0, peers=block, x=0.0):
        return planner.step(0.0, np.array([x, 0.0, heading]), peers=peers)

    column = DetourPlanner(path, R, True, DT, config=cfg)
    step = first(column)
    assert column.plan is not None and column.plan.reason == "held" and step.turn is not None
    want, heading = step.turn
    assert -1.45 < want < -0.8 and heading == 0.0  # to the right (the default side), steeply
    assert step.pose[2] == pytest.approx(-want)  # the controller sees the lane turned as much
    # turned most of the way: still turning (hysteresis), then within 0.3925 rad: done
    assert column.step(0.1, np.array([0.0, 0.0, want + 0.5]), peers=block).turn is not None
    done = column.step(0.2, np.array([0.0, 0.0, want + 0.3]), peers=block)
    assert done.turn is None and done.pose[2] == pytest.approx(0.3)  # it drives on out
    assert column.step(0.3, np.array([0.0, 0.0, want + 0.6]), peers=block).turn is None  # 0.785 to engage again
    assert first(DetourPlanner(path, R, True, DT)).turn is None  # a path of its own: the default
    assert first(DetourPlanner(path, R, False, DT, config=cfg)).turn is None  # omni
    box = DetourPlanner(path, R, True, DT, known=[(_box(0.55, 0.0), (0.0, 0.0))], config=cfg)
    assert first(box, peers=()).turn is None and box.plan is not None  # a box, not a held robot
    quiet = DetourPlanner(path, R, True, DT, config=cfg)  # the held robot is only quiet: its disc grows
    silent = quiet.step(0.0, np.array([0.0, 0.0, 0.0]), peers=block, quiet_held=True)
    assert quiet.plan is not None and silent.turn is None and silent.pose[2] == 0.0  # shown its own heading
    edge = DetourPlanner(path, R, True, DT, config=cfg)  # 0.3 m from its centre: within 0.2 m + the width, 0.13 m
    reached = first(edge, x=0.25)
    assert edge.plan is not None and reached.turn is None and edge.plan.entered


def test_the_turn_on_the_spot_stops_and_turns_within_the_bases_limits():
    """The command while turning: forward speed to 0 and a turn towards the heading, capped at
    omega_max, reached from the applied command at a_max and alpha_max as the base would."""
    from copath.models import UnicycleModel  # noqa: PLC0415

    model = UnicycleModel(v_max=0.5, omega_max=1.0, a_max=0.3, alpha_max=1.0)
    assert turn_command([0.2, 0.0], None) == [0.2, 0.0]  # not turning: the controller's own
    free = turn_command([0.2, 0.0], (-1.0, 0.0))
    assert free[0] == 0.0 and free[1] == pytest.approx(-2.0)  # no model: 2 rad/s per radian
    capped = turn_command([0.2, 0.0], (-1.0, 0.0), model)
    assert capped.tolist() == [0.0, -1.0]
    step = turn_command([0.2, 0.0], (-1.0, 0.0), model, applied=np.array([0.2, 0.0]), dt=DT)
    assert abs(step[0] - 0.2) <= 0.3 * DT + 1e-12 and abs(step[1]) <= 1.0 * DT + 1e-12
    assert step[0] < 0.2 and step[1] < 0.0  # on its way to (0, -1)


def test_a_robot_turning_on_the_spot_has_not_given_up_its_detour():
    """No progress while it turns first is not a stalled detour (the give-up after ``stall_s``
    counts from the last turning instant): a robot held facing the block for 8 s keeps its
    detour; the same robot not turning gives it up after 4 s."""
    path = line((-1.0, 0.0), 0.0, 20.0)
    block = [(0.55, 0.0, 0.2, True)]

    def given_up(planner, forget_turn: bool):
        for k in range(80):
            planner.step(k * DT, np.array([0.0, 0.0, 0.0]), peers=block, pressed=True)
            if forget_turn:
                planner._turned_at = -math.inf
            if planner.plan is not None and planner.plan.abandoned:
                return k * DT
        return None

    assert given_up(DetourPlanner(path, R, True, DT, config=DetourConfig(turn_first=True)), False) is None
    assert given_up(DetourPlanner(path, R, True, DT, config=DetourConfig(turn_first=True)), True) == pytest.approx(4.0)


def test_the_steepest_slope_of_the_ramp_in_ahead():
    """``DetourPlan.steepest_in``: the steepest slope of the ramp in from a point on, the
    smoothstep's half-way slope (15/8 of the mean) before half way, the slope itself after; the
    densely sampled maximum agrees."""
    path = line((-1.0, 0.0), 0.0, 20.0)
    planner = DetourPlanner(path, R, True, DT, config=DetourConfig(turn_first=True))
    planner.step(0.0, np.array([0.0, 0.0, 0.0]), peers=[(0.55, 0.0, 0.2, True)])
    plan = planner.plan
    start = plan.u_lo - plan.ramp_in
    for u in (start - 0.1, start, start + 0.3 * plan.ramp_in, start + 0.7 * plan.ramp_in, plan.u_lo - 1e-6):
        s = plan.s0 + plan.direction * u
        dense = [plan.slope(plan.s0 + plan.direction * x) for x in np.linspace(max(u, start), plan.u_lo, 2001)]
        assert plan.steepest_in(s) == pytest.approx(max(dense, key=abs), rel=1e-5)
    assert abs(plan.steepest_in(plan.s0 + plan.direction * start)) == pytest.approx(
        1.875 * abs(plan.height) / plan.ramp_in)
