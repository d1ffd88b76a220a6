"""Pieces of the Chapter 6 roles controller: principal axis by power iteration
(Algorithm 6.1), formation placement (6.3), local Hungarian and negotiation
(Algorithm 6.2), navigation (6.10)-(6.15) and PI dynamic consensus (6.16)."""

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.optimize import linear_sum_assignment

from agent.controllers.roles.assignment import Claim, RoleBook, Ruling, assignment_cost, local_hungarian, nearest_position
from agent.controllers.roles.config import RolesConfig
from agent.controllers.roles.averaging import PIConsensus
from agent.controllers.roles.navigation import (
    NavigationGains,
    parking_point,
    polar_control,
    repulsion_magnitude,
    repulsive_shift,
)
from agent.controllers.roles.rotation import (
    canonical_axis,
    covariance_from_moments,
    moment_vector,
    power_iteration,
    principal_axis,
    principal_axis_ac,
    template_frame,
    transform_targets,
)
from copath.config import ConfigError, from_table
from copath.models import UnicycleModel
from tests.conftest import is_connected


def _random_graph(P, r):
    D = np.hypot(*(P[:, None] - P[None]).transpose(2, 0, 1))
    return (D < r) & ~np.eye(len(P), dtype=bool)


# -- Algorithm 6.1: principal axis --------------------------------------------------------

@given(st.integers(0, 10**6), st.integers(4, 20), st.floats(0.0, math.pi), st.floats(1.5, 4.0))
def test_power_iteration_finds_the_principal_axis_up_to_sign(seed, n, angle, aspect):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(n, 2)) * np.array([aspect, 1.0])
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    P = P @ R.T + rng.uniform(-5, 5, 2)
    C = np.cov(P.T, bias=True)
    lam, V = np.linalg.eigh(C)
    if lam[1] < 1.2 * lam[0]:  # the fallback case is tested separately
        assert principal_axis(C) is None
        return
    q, _ = power_iteration(C)
    assert abs(abs(q @ V[:, 1]) - 1.0) < 1e-6  # same axis, up to the sign
    assert q[0] > 0 or (abs(q[0]) < 1e-9 and q[1] > 0)  # canonical sign (docs/reference/ambiguities.md, start vector and principal axis (A23))
    th = principal_axis(C)
    assert abs(math.sin(th - math.atan2(V[1, 1], V[0, 1]))) < 1e-5


@settings(max_examples=25)
@given(st.integers(0, 10**6))
def test_algorithm_6_1_over_consensus_agrees_with_the_centralised_axis(seed):
    rng = np.random.default_rng(seed)
    while True:
        P = rng.uniform(0, 3, (10, 2)) * np.array([1.0, 0.4])
        A = _random_graph(P, 1.2)
        if is_connected(A):
            break
    C = np.cov(P.T, bias=True)
    lam, V = np.linalg.eigh(C)
    q = principal_axis_ac(P, A, rounds=400)
    # every robot reaches the same canonical axis, equal to the centralised one up to sign
    assert np.allclose(q, q[0], atol=1e-6)
    assert abs(abs(q[0] @ V[:, 1]) - 1.0) < 1e-6
    # the moment-vector form used by the controller gives the same axis
    c, C2 = covariance_from_moments(np.mean([moment_vector(p) for p in P], axis=0))
    np.testing.assert_allclose(c, P.mean(axis=0), atol=1e-12)
    np.testing.assert_allclose(C2, C, atol=1e-12)


def test_isotropic_formations_fall_back_to_no_rotation():
    a = np.arange(12) * 2 * math.pi / 12
    circle = np.c_[np.cos(a), np.sin(a)]
    assert template_frame(circle)[1] is None
    square = np.array([(x, y) for x in range(3) for y in range(3)], dtype=float)
    assert template_frame(square)[1] is None
    line = np.c_[np.arange(5.0), np.zeros(5)]
    assert template_frame(line)[1] == pytest.approx(0.0, abs=1e-9)


def test_canonical_axis_sign():
    np.testing.assert_allclose(canonical_axis([-1.0, -1.0]), np.array([1.0, 1.0]) / math.sqrt(2))
    np.testing.assert_allclose(canonical_axis([0.0, -2.0]), [0.0, 1.0])


@given(st.floats(-math.pi, math.pi), st.floats(-3, 3), st.floats(-3, 3))
def test_transform_targets_is_a_ccw_rotation_about_the_centroid(rot, cx, cy):
    T = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 1.0]])
    G = transform_targets(T, (cx, cy), rot)
    np.testing.assert_allclose(G.mean(axis=0), [cx, cy], atol=1e-12)
    # distances preserved, orientation counter-clockwise (docs/reference/ambiguities.md, rotation direction and order of translation (A22))
    np.testing.assert_allclose(np.hypot(*(G[1] - G[0])), 2.0, atol=1e-12)
    d = G[1] - G[0]
    assert math.atan2(d[1], d[0]) == pytest.approx(rot, abs=1e-9) or abs(abs(rot) - math.pi) < 1e-9


# -- Algorithm 6.2: assignment and negotiation --------------------------------------------

@given(st.integers(0, 10**6), st.integers(1, 8), st.integers(1, 8))
def test_local_hungarian_with_full_knowledge_is_the_global_optimum(seed, n, m):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, 2))
    G = rng.uniform(-2, 2, (m, 2))
    C = assignment_cost(X, G)
    rows, cols = linear_sum_assignment(C)
    own = local_hungarian(X[0], X[1:], G, range(m))
    expect = int(cols[rows == 0][0]) if np.any(rows == 0) else None
    if expect is None:
        assert own is None  # more robots than positions: no column for this one
    else:
        # equal cost (ties may pick another column with the same optimum)
        assert C[0, own] == pytest.approx(C[0, expect], abs=1e-9) or own == expect


def test_nearest_position_and_empty_sets():
    G = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    assert nearest_position([2.2, 0.0], G, [0, 1, 2]) == 2
    assert nearest_position([2.2, 0.0], G, [0, 1]) == 1
    assert nearest_position([2.2, 0.0], G, []) is None
    assert local_hungarian([0, 0], [], G, []) is None


def test_negotiation_initiator_and_ties():
    book = RoleBook("r5", 5, 4)
    book.claim(2)
    lower_far = Claim("r1", 1, 2, 1.0)
    rulings, waiting = book.negotiate(1.0, book.conflicts([lower_far]))
    assert not waiting and rulings == [Ruling(2, "r5", "r1")]  # tie: the initiator wins
    assert book.conflicts_initiated == 1
    rulings, _ = book.negotiate(1.0, book.conflicts([lower_far]))
    assert book.conflicts_initiated == 1  # a repeated ruling is not a new negotiation
    higher = Claim("r7", 7, 2, 0.1)
    rulings, waiting = book.negotiate(1.0, book.conflicts([higher]))
    assert waiting and rulings == []  # the higher index decides
    assert book.lost([Ruling(2, "r7", "r5")])


def test_a_ruling_is_final_when_the_distances_change():
    """The initiator repeats its ruling: made again from the distances of a later step it
    would go the other way here, after the loser has already left on the first one, and
    the position would be left empty (docs/reference/controllers-notes.md, ruling of the
    negotiation is final (N9); the pair and distances of E6.1 with the one-hop exchange)."""
    book = RoleBook("r13", 12, 10)
    book.claim(9)
    rulings, _ = book.negotiate(0.887, book.conflicts([Claim("r9", 8, 9, 0.891)]))
    assert rulings == [Ruling(9, "r13", "r9")]
    rulings, _ = book.negotiate(0.865, book.conflicts([Claim("r9", 8, 9, 0.857)]))  # r9 moved on
    assert rulings == [Ruling(9, "r13", "r9")] and book.position == 9
    assert book.conflicts_initiated == 1


def _negotiate_team(claims0, dist, n_pos, rounds, loss, rng, speed=0.0):
    """Robots exchange claims, taken sets and rulings (with loss) until settled; with
    ``speed`` every robot moves towards its claimed position by up to that much per round
    (its distances to the other positions kept), so the distances a ruling compares change."""
    names = [f"r{i}" for i in range(len(claims0))]
    books = {n: RoleBook(n, i, n_pos) for i, n in enumerate(names)}
    for n, c in zip(names, claims0):
        books[n].claim(c)
    outbox = {n: [] for n in names}
    heard = {n: {} for n in names}
    for _ in range(rounds):
        msgs = {n: (books[n].position, sorted(books[n].taken), list(outbox[n]), dist[n][books[n].position]
                    if books[n].position >= 0 else math.inf) for n in names}
        for r in names:
            for s in names:
                if s != r and rng.random() >= loss:
                    heard[r][s] = msgs[s]
        for i, n in enumerate(names):
            b = books[n]
            b.merge((h[1] for h in heard[n].values()), (h[0] for h in heard[n].values()))
            incoming = [Ruling(*x) for h in heard[n].values() for x in h[2] if n in x[1:]]
            if b.position >= 0 and b.lost(incoming):
                b.claim(nearest_position(np.zeros(2), np.zeros((n_pos, 2)), [k for k in b.available if k != b.position]))
            claims = [Claim(s, names.index(s), h[0], h[3]) for s, h in heard[n].items() if h[0] >= 0]
            conf = b.conflicts(claims)
            rulings, _ = b.negotiate(dist[n][b.position] if b.position >= 0 else math.inf, conf)
            outbox[n] = [(r.position, r.winner, r.loser) for r in rulings]
            if any(r.loser == n for r in rulings):
                b.claim(nearest_position(np.zeros(2), np.zeros((n_pos, 2)), [k for k in b.available if k != b.position]))
            if speed > 0 and b.position >= 0:
                dist[n][b.position] = max(0.0, dist[n][b.position] - speed * rng.random())
    return books


@settings(max_examples=40)
@given(st.integers(0, 10**6), st.integers(2, 9), st.integers(1, 9), st.sampled_from([0.0, 0.2]),
       st.sampled_from([0.0, 0.2]))
@example(seed=2, n=8, m=1, loss=0.0, speed=0.2)  # both claimants left it before rulings were final
def test_negotiation_never_leaves_two_robots_on_one_position(seed, n, m, loss, speed):
    rng = np.random.default_rng(seed)
    claims = rng.integers(0, m, n)  # everybody starts with a (possibly shared) claim
    dist = {f"r{i}": rng.uniform(0.1, 3.0, m) for i in range(n)}
    books = _negotiate_team(list(claims), dist, m, rounds=60, loss=loss, rng=rng, speed=speed)
    held = [b.position for b in books.values() if b.position >= 0]
    assert len(held) == len(set(held))  # no position held twice
    assert len(held) == min(n, m)  # and no position left empty while a robot has none
    # every originally contested position went to one of its claimants
    for k in set(claims):
        holders = [nme for nme, b in books.items() if b.position == k]
        assert len(holders) == 1


# -- navigation (6.10)-(6.15) --------------------------------------------------------------

@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(-math.pi, math.pi))
def test_polar_control_respects_its_bounds(x, y, th):
    v, w = polar_control((x, y, th), (0.3, -0.2), k_c=1.0, gamma=0.5)
    assert abs(v) <= 0.5 + 1e-12
    assert abs(w) <= 1.0 * math.pi + 0.5 / 2 + 1e-9  # |omega_max| = k_c pi + gamma / 2


@given(st.floats(-2, 2), st.floats(-2, 2), st.floats(-math.pi, math.pi))
def test_navigation_law_drives_a_unicycle_to_the_target(x, y, th):
    model = UnicycleModel(v_max=0.5, omega_max=3.4)
    pose = np.array([x, y, th])
    goal = np.array([0.4, -0.3])
    for _ in range(400):  # 40 s at 0.1 s
        cmd, _ = model.saturate(polar_control(pose, goal, 1.0, 0.5, stop_radius=0.005))
        pose = model.step(pose, cmd, 0.1)
    assert np.hypot(*(pose[:2] - goal)) < 0.02


def test_repulsion_magnitudes_of_spec():
    # (6.12) with k_r = 0.2, R_max = 0.4 (docs/reference/derivations.md, repulsive target shift (D9)):
    # 0.58 m at 0.35 m, 1.85 m at 0.30, 12.5 m at 0.20
    assert repulsion_magnitude(0.35, 0.2, 0.4) == pytest.approx(0.58, abs=0.01)
    assert repulsion_magnitude(0.30, 0.2, 0.4) == pytest.approx(1.85, abs=0.01)
    assert repulsion_magnitude(0.20, 0.2, 0.4) == pytest.approx(12.5, abs=0.01)
    assert repulsion_magnitude(0.45, 0.2, 0.4) == 0.0
    assert repulsion_magnitude(0.20, 0.2, 0.4, F_max=5.0) == 5.0


def test_repulsive_shift_moves_the_target_away_and_sideways():
    g = NavigationGains()
    p, goal = np.array([0.0, 0.0]), np.array([2.0, 0.0])
    assert np.allclose(repulsive_shift(p, goal, [[0.0, 1.0]], g), goal)  # beyond R_max
    behind = repulsive_shift(p, goal, [[-0.3, 0.0]], g)
    assert behind[0] > goal[0] and abs(behind[1]) < 1e-12  # pushed forward, straight
    ahead = repulsive_shift(p, goal, [[0.3, 0.0]], g)
    F = repulsion_magnitude(0.3, g.k_r, g.R_max, g.F_max)
    np.testing.assert_allclose(ahead, goal + [-F, -g.side * F])  # back off and keep right
    two = repulsive_shift(p, goal, [[0.0, 0.3], [0.0, -0.35]], g)
    F1, F2 = (repulsion_magnitude(r, g.k_r, g.R_max, g.F_max) for r in (0.3, 0.35))
    np.testing.assert_allclose(two, goal + [0.0, -F1 + F2], atol=1e-12)  # displacements summed


def test_head_on_robots_pass_without_touching():
    g = NavigationGains()
    model = UnicycleModel(v_max=0.5, omega_max=3.4)
    a, b = np.array([-1.5, 0.0, 0.0]), np.array([1.5, 0.0, math.pi])
    ga, gb = np.array([1.5, 0.0]), np.array([-1.5, 0.0])
    dmin = math.inf
    for _ in range(300):
        pa, pb = a[:2].copy(), b[:2].copy()  # each sees the other one step late
        ca, _ = model.saturate(polar_control(a, repulsive_shift(a[:2], ga, [pb], g), 1.0, 0.5, 0.01))
        cb, _ = model.saturate(polar_control(b, repulsive_shift(b[:2], gb, [pa], g), 1.0, 0.5, 0.01))
        a, b = model.step(a, ca, 0.1), model.step(b, cb, 0.1)
        dmin = min(dmin, float(np.hypot(*(a[:2] - b[:2]))))
    assert dmin > 0.12  # discs of 0.06 m never touch
    assert np.hypot(*(a[:2] - ga)) < 0.05 and np.hypot(*(b[:2] - gb)) < 0.05


@given(st.integers(0, 10**6))
def test_parking_point_keeps_clear_of_the_formation(seed):
    rng = np.random.default_rng(seed)
    T = rng.uniform(-1, 1, (8, 2))
    p = rng.uniform(-2, 2, 2)
    q = parking_point(p, T.mean(axis=0), T, 0.5)
    assert np.min(np.hypot(*(T - q).T)) >= 0.5 - 1e-9
    q2 = parking_point(p, T.mean(axis=0), T, 0.5, avoid=[q])
    assert np.hypot(*(q2 - q)) >= 0.5 - 1e-9
    assert np.min(np.hypot(*(T - q2).T)) >= 0.5 - 1e-9


# -- (6.16) PI dynamic consensus ---------------------------------------------------------

def _pi_team(A, finish, k_z, T=60.0, dt=0.1):
    n = len(A)
    deg = A.sum(axis=1)
    pis = [PIConsensus(k_z, 8.0, 4.0) for _ in range(n)]
    last = [(1.0, 0.0, int(deg[i])) for i in range(n)]  # messages arrive one step late
    zs, ws = [], []
    for k in range(int(T / dt)):
        t = k * dt
        w = np.array([0.0 if t >= finish[i] else 1.0 for i in range(n)])
        for i in range(n):
            pis[i].step(w[i], [last[j] for j in np.nonzero(A[i])[0]], dt)
        last = [(p.z, p.eta, int(deg[i])) for i, p in enumerate(pis)]
        zs.append([p.z for p in pis])
        ws.append(w.mean())
    return np.array(zs), np.array(ws)


@settings(max_examples=20)
@given(st.integers(0, 10**6), st.sampled_from([(16, 1.5, 0.2), (6, 1.2, 0.5)]))
def test_pi_consensus_tracks_the_fraction_of_unfinished_robots(seed, team):
    n, r, k_z = team
    rng = np.random.default_rng(seed)
    while True:
        P = rng.uniform(-1.5, 1.5, (n, 2))
        A = _random_graph(P, r)
        if is_connected(A):
            break
    finish = rng.uniform(5.0, 15.0, n)
    finish[rng.integers(n)] = np.inf  # one robot never finishes
    # 90 s: on the sparsest 16-robot graphs drawn (algebraic connectivity 0.15-0.30) the
    # estimates were still 0.022-0.023 off at 60 s (2 of 301 seeds; 0.006-0.011 at 90 s)
    zs, wbar = _pi_team(A, finish, k_z, T=90.0)
    # after the transient every estimate is within 0.02 of the true fraction 1/n
    np.testing.assert_allclose(zs[-1], 1.0 / n, atol=0.02)
    # while two or more robots are still working, nobody's estimate falls to 0.1 (E6.5's
    # threshold is below 1/6 only when one robot is left)
    busy = wbar >= 2.0 / n - 1e-9
    assert np.all(zs[busy] > 0.1)


def test_pi_consensus_reset_and_config_validation():
    pi = PIConsensus(0.2)
    pi.z, pi.eta = 0.05, 0.3
    pi.reset()
    assert (pi.z, pi.eta) == (1.0, 0.0)  # docs/reference/ambiguities.md, reset at a task switch (A26)
    with pytest.raises(ConfigError, match="orientation"):
        from_table(RolesConfig, {"formations": [[[0, 0]]], "orientation": "random"}, "controller")
    with pytest.raises(ConfigError, match="formations"):
        from_table(RolesConfig, {}, "controller")
    cfg = from_table(RolesConfig, {"formations": [[[0, 0], [1, 0]]]}, "controller")
    assert cfg.formations == (((0.0, 0.0), (1.0, 0.0)),)
