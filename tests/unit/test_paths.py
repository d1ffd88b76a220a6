"""Path geometry: arc length, curvature, tangents, nearest point (docs/reference/conventions.md, frames and angles and arc-length paths (C1-C2))."""

import math

import numpy as np
import pytest

from copath.paths import circle, ellipse, eight_curve, lemniscate, line, make_path, sinusoid, spline, wrap_to_pi


def test_eight_curve_length_and_peak_curvature():
    p = eight_curve(1.8, 1.2)
    assert p.length == pytest.approx(12.86, abs=0.005)  # docs/reference/derivations.md, published path lengths (D5): 12.86 m
    k = p.kappa(np.linspace(0, p.length, 4000))
    assert np.abs(k).max() == pytest.approx(3.28, abs=0.01)  # published path lengths (D5): kappa_max ~ 3.28


def test_lemniscate_length_and_curvature():
    p = lemniscate(2.3)
    assert p.length == pytest.approx(12.06, abs=0.01)  # docs/reference/derivations.md, published path lengths (D5)
    assert np.abs(p.kappa(np.linspace(0, p.length, 4000))).max() == pytest.approx(1.30, abs=0.01)


@pytest.mark.parametrize("radius", [0.5, 1.0, 2.5])
def test_circle_curvature_is_inverse_radius(radius):
    p = circle(radius)
    s = np.linspace(0, p.length, 50)
    np.testing.assert_allclose(p.kappa(s), 1.0 / radius, rtol=1e-6)
    assert p.length == pytest.approx(2 * math.pi * radius, rel=1e-9)
    # E4.4 circle: CCW, theta = s/R + pi/2 at x = R cos(s/R)
    np.testing.assert_allclose(p.theta(s), s / radius + math.pi / 2, atol=1e-6)


def test_arc_length_parameterisation_has_unit_speed():
    for p in (eight_curve(), lemniscate(), ellipse(1.5, 1.0, math.pi / 6), spline([[0, 0], [1, 1], [2, 0], [3, 1]])):
        s = np.linspace(0, p.length, 3001)
        step = np.hypot(*np.diff(p.pos(s), axis=0).T)
        np.testing.assert_allclose(step / np.diff(s), 1.0, atol=2e-4)


def test_tangent_matches_finite_difference_and_is_continuous_across_laps():
    p = ellipse(1.5, 1.0, rotation=math.pi / 6, center=(0.3, -0.2))
    s = np.linspace(-3.0, 2 * p.length + 1.0, 777)
    h = 1e-5
    d = (p.pos(s + h) - p.pos(s - h)) / (2 * h)
    np.testing.assert_allclose(wrap_to_pi(np.arctan2(d[:, 1], d[:, 0]) - p.theta(s)), 0.0, atol=1e-5)
    assert np.abs(np.diff(p.theta(s))).max() < 0.1  # no 2 pi jumps


def test_curvature_matches_turning_rate_and_dkappa():
    p = lemniscate(2.3)
    s = np.linspace(0.1, p.length - 0.1, 301)
    h = 1e-4
    np.testing.assert_allclose((p.theta(s + h) - p.theta(s - h)) / (2 * h), p.kappa(s), atol=1e-4)
    np.testing.assert_allclose((p.kappa(s + h) - p.kappa(s - h)) / (2 * h), p.dkappa(s), atol=2e-2)


def test_open_path_extends_straight_beyond_ends():
    p = line((1.0, 2.0), math.pi / 2, 3.0)
    np.testing.assert_allclose(p.pos(4.0), [1.0, 6.0], atol=1e-9)
    np.testing.assert_allclose(p.pos(-1.0), [1.0, 1.0], atol=1e-9)
    assert p.kappa(5.0) == 0.0
    sp = sinusoid(0.2, 2.0, 6.0)
    assert not sp.closed and sp.wrap(7.0) == 7.0


def test_nearest_recovers_the_foot_point():
    p = eight_curve()
    rng = np.random.default_rng(3)
    for s0 in rng.uniform(0, p.length, 20):
        foot = p.pos(s0)
        q = rng.uniform(-0.05, 0.05)
        point = foot + q * p.normal(s0)
        s = p.nearest(point, s0 + rng.uniform(-0.3, 0.3))
        assert abs(p.wrap(s) - p.wrap(s0)) < 1e-4 or abs(abs(p.wrap(s) - p.wrap(s0)) - p.length) < 1e-4


def test_casadi_tables_match_numpy():
    p = ellipse(1.5, 1.0, math.pi / 6)
    f = p.casadi()
    for s in (0.3, 2.0, p.length + 0.7, -0.4):
        assert float(f["x"](s)) == pytest.approx(p.pos(s)[0], abs=1e-4)
        assert float(f["y"](s)) == pytest.approx(p.pos(s)[1], abs=1e-4)
        assert float(f["kappa"](s)) == pytest.approx(p.kappa(s), abs=2e-3)
        assert wrap_to_pi(float(f["theta"](s)) - p.theta(s)) == pytest.approx(0.0, abs=1e-4)


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"type": "spiral"}, "path type = 'spiral' is not allowed"),
        ({"type": "circle"}, "needs keys ['radius']"),
        ({"type": "circle", "radius": 1.0, "colour": 3}, "path key 'colour' (= 3) is not allowed"),
        ({"type": "spline", "waypoints": [[0, 0], [1, 1]]}, "at least 3"),
    ],
)
def test_make_path_errors_name_key_value_and_rule(spec, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[").replace("]", r"\]")):
        make_path(spec)
