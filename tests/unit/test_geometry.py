"""sim/geometry.py: ray casting against convex polygons, signed distances, clearance."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from sim.geometry import PolygonObstacle, clearance, point_polygon_distance, ray_cast

SQUARE = np.array([[1.0, -0.5], [2.0, -0.5], [2.0, 0.5], [1.0, 0.5]])  # counter-clockwise
RING = np.deg2rad(np.arange(0, 360, 30))  # 12 rays every 30 deg (Sec. 4.4.3)


def test_ray_hits_front_face_and_misses_elsewhere():
    r = ray_cast([0.0, 0.0], 0.0, RING, 1.5, [SQUARE])
    assert r[0] == pytest.approx(1.0)
    assert np.all(np.isinf(r[1:]))  # 30 deg: y = 0.577 at x = 1 passes above the box


def test_ray_heading_rotates_the_bearings():
    r = ray_cast([0.0, 0.0], -math.pi / 2, RING, 1.5, [SQUARE])  # facing -y: the box is at +90 deg bearing
    assert r[3] == pytest.approx(1.0) and np.isinf(r[0])


def test_ray_oblique_hit_and_max_range():
    r = ray_cast([0.0, 0.0], 0.0, np.array([math.radians(20)]), 2.0, [SQUARE])
    assert r[0] == pytest.approx(1.0 / math.cos(math.radians(20)))
    assert np.isinf(ray_cast([0.0, 0.0], 0.0, np.array([0.0]), 0.99, [SQUARE])[0])


def test_ray_nearest_of_several_polygons_and_clockwise_orientation():
    near = SQUARE[::-1] - [0.5, 0.0]  # clockwise copy, 0.5 m closer
    r = ray_cast([0.0, 0.0], 0.0, np.array([0.0]), 5.0, [SQUARE, near])
    assert r[0] == pytest.approx(0.5)


def test_ray_from_inside_reads_zero_and_no_polygons_reads_inf():
    assert np.all(ray_cast([1.5, 0.0], 0.3, RING, 0.5, [SQUARE]) == 0.0)
    assert np.all(np.isinf(ray_cast([0.0, 0.0], 0.0, RING, 0.5, [])))


def test_point_polygon_distance_signed():
    assert point_polygon_distance([0.0, 0.0], SQUARE) == pytest.approx(1.0)
    assert point_polygon_distance([3.0, 1.5], SQUARE) == pytest.approx(math.sqrt(2.0))  # vertex
    assert point_polygon_distance([1.5, 0.0], SQUARE) == pytest.approx(-0.5)  # inside
    assert point_polygon_distance([1.5, 0.0], SQUARE[::-1]) == pytest.approx(-0.5)
    assert point_polygon_distance([1.0, 0.2], SQUARE) == pytest.approx(0.0, abs=1e-12)


def test_clearance_of_a_disc():
    assert clearance([0.0, 0.0], 0.2, [SQUARE]) == pytest.approx(0.8)
    assert clearance([0.9, 0.0], 0.2, [SQUARE]) == pytest.approx(-0.1)  # overlapping: collision
    assert clearance([0.0, 0.0], 0.2, []) == math.inf


def test_polygon_obstacle_moves_with_its_velocity():
    o = PolygonObstacle(SQUARE, np.array([0.2, -0.1]))
    np.testing.assert_allclose(o.at(2.0), SQUARE + [0.4, -0.2])
    with pytest.raises(ValueError):
        PolygonObstacle(np.zeros((2, 2)))


def _regular_polygon(center, radius, n, phase):
    a = phase + 2 * math.pi * np.arange(n) / n
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=1)


coords = st.floats(-3.0, 3.0, allow_nan=False)


@given(cx=coords, cy=coords, radius=st.floats(0.1, 1.0), n=st.integers(3, 8), phase=st.floats(0, 6.3),
       ox=coords, oy=coords, heading=st.floats(-math.pi, math.pi))
def test_ray_hits_lie_on_the_boundary_and_not_closer_than_the_polygon(cx, cy, radius, n, phase, ox, oy, heading):
    poly = _regular_polygon((cx, cy), radius, n, phase)
    origin = np.array([ox, oy])
    d0 = point_polygon_distance(origin, poly)
    r = ray_cast(origin, heading, RING, 10.0, [poly])
    if d0 <= 0:
        assert np.all(r == 0.0)
        return
    for ang, ri in zip(RING, r):
        if np.isfinite(ri):
            hit = origin + ri * np.array([math.cos(heading + ang), math.sin(heading + ang)])
            assert abs(point_polygon_distance(hit, poly)) < 1e-7
            assert ri >= d0 - 1e-9


@given(cx=coords, cy=coords, radius=st.floats(0.1, 1.0), n=st.integers(3, 8), phase=st.floats(0, 6.3),
       px=coords, py=coords)
def test_distance_agrees_with_vertex_bound_and_sign(cx, cy, radius, n, phase, px, py):
    poly = _regular_polygon((cx, cy), radius, n, phase)
    p = np.array([px, py])
    d = point_polygon_distance(p, poly)
    # never farther than the nearest vertex; negative exactly when inside the inscribed test
    assert d <= np.min(np.linalg.norm(poly - p, axis=1)) + 1e-12
    r_in = radius * math.cos(math.pi / n)
    dc = math.hypot(px - cx, py - cy)
    if dc < r_in - 1e-9:
        assert d < 0
    if dc > radius + 1e-9:
        assert d > 0
