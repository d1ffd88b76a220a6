"""Average consensus of Chapter 6 reaches the exact average on any connected undirected
graph without knowing N ((2.21) read as docs/reference/ambiguities.md, average consensus with 1/|N_i| (A21)): the synchronous Metropolis
iteration, and the per-robot edge-flow form under message delay, loss and a changing
neighbour set."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.controllers.roles.averaging import (
    AverageConsensus,
    NeighbourContribution,
    metropolis_step,
    metropolis_weights,
)


@st.composite
def connected_graphs(draw, n_min=2, n_max=12):
    """A random connected undirected graph: a random spanning tree plus random extra edges."""
    n = draw(st.integers(n_min, n_max))
    A = np.zeros((n, n), dtype=bool)
    order = draw(st.permutations(list(range(n))))
    for k in range(1, n):
        parent = order[draw(st.integers(0, k - 1))]
        A[order[k], parent] = A[parent, order[k]] = True
    extra = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=2 * n))
    for i, j in extra:
        if i != j:
            A[i, j] = A[j, i] = True
    return A


values = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


def _spectral_steps(W, tol=1e-10):
    """Steps after which W^k x is within tol of the average for |x| <= 10 (second eigenvalue)."""
    lam = np.sort(np.abs(np.linalg.eigvalsh(W)))[-2] if len(W) > 1 else 0.0
    return int(np.ceil(np.log(tol / (10.0 * len(W))) / np.log(max(lam, 1e-12)))) + 1


@given(connected_graphs(), st.data())
def test_metropolis_weights_are_symmetric_and_doubly_stochastic(A, data):
    W = metropolis_weights(A)
    np.testing.assert_allclose(W, W.T, atol=1e-15)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(W >= -1e-15)
    # zero weight off the graph
    off = ~A & ~np.eye(len(A), dtype=bool)
    assert np.all(W[off] == 0.0)


@given(connected_graphs(), st.data())
def test_metropolis_iteration_reaches_the_exact_average(A, data):
    n = len(A)
    x0 = np.array(data.draw(st.lists(values, min_size=n, max_size=n)))
    W = metropolis_weights(A)
    x = x0.copy()
    for _ in range(min(_spectral_steps(W), 20000)):
        x = metropolis_step(x, A)
        np.testing.assert_allclose(x.sum(), x0.sum(), atol=1e-9)  # the average is invariant
    np.testing.assert_allclose(x, x0.mean(), atol=1e-8)


def _run_async(A_of_tick, v, ticks, delay, loss, rng):
    """Robots running AverageConsensus over messages delayed by ``delay`` ticks and lost
    with probability ``loss``; A_of_tick(k) gives the graph at tick k. A message carries
    (estimate, degree, own contribution to the receiver, echo of the receiver's)."""
    n = len(v)
    robots = [AverageConsensus(v[i]) for i in range(n)]
    names = [f"r{i}" for i in range(n)]
    latest = [dict() for _ in range(n)]  # receiver -> sender -> (estimate, degree, flow)
    queue = []  # (deliver_tick, receiver, sender, message)
    degree = [0] * n
    for k in range(ticks):
        A = A_of_tick(k)
        keep = []
        for item in queue:
            if item[0] <= k:
                latest[item[1]][item[2]] = item[3]
            else:
                keep.append(item)
        queue = keep
        for i in range(n):
            for sender, msg in latest[i].items():
                robots[i].absorb(sender, msg[2])
            nbrs = {names[j]: NeighbourContribution(*latest[i][names[j]])
                    for j in np.nonzero(A[i])[0] if names[j] in latest[i]}
            robots[i].step(nbrs)
            degree[i] = len(nbrs)
        for i in range(n):
            for j in np.nonzero(A[i])[0]:
                if rng.random() < loss:
                    continue
                msg = (robots[i].estimate.copy(), degree[i], robots[i].flow_to(names[j]).copy(),
                       robots[i].echo_to(names[j]).copy())
                queue.append((k + delay, j, names[i], msg))
    # flush: deliver everything in flight and let every robot take in its flows once more
    for item in queue:
        latest[item[1]][item[2]] = item[3]
    for i in range(n):
        for sender, msg in latest[i].items():
            robots[i].absorb(sender, msg[2])
    return np.array([r.estimate for r in robots]), robots


@pytest.mark.faults  # tier: README "Test tiers"
@settings(max_examples=20)
@given(connected_graphs(n_min=3, n_max=10), st.integers(1, 4), st.sampled_from([0.0, 0.1, 0.3]), st.integers(0, 10**6),
       st.data())
def test_edge_flow_consensus_reaches_the_average_under_delay_and_loss(A, delay, loss, seed, data):
    n = len(A)
    v = np.array(data.draw(st.lists(st.tuples(values, values), min_size=n, max_size=n)))
    rng = np.random.default_rng(seed)
    W = metropolis_weights(A)
    ticks = min(3 * _spectral_steps(W, tol=1e-7) + 100 * delay, 6000)
    x, _ = _run_async(lambda k: A, v, ticks, delay, loss, rng)
    np.testing.assert_allclose(x.sum(axis=0), v.sum(axis=0), atol=1e-9)  # exact once flows have arrived
    np.testing.assert_allclose(x, np.broadcast_to(v.mean(axis=0), x.shape), atol=1e-5)


@settings(max_examples=15)
@given(connected_graphs(n_min=3, n_max=8), st.integers(0, 10**6), st.data())
def test_edge_flow_consensus_keeps_the_average_when_links_come_and_go(A, seed, data):
    """Extra links switch on and off every few ticks while a spanning set stays; the
    average of the inputs is never lost."""
    n = len(A)
    v = np.array(data.draw(st.lists(values, min_size=n, max_size=n)))[:, None]
    rng = np.random.default_rng(seed)
    full = A | (rng.random((n, n)) < 0.4)
    full = np.triu(full, 1)
    full = full | full.T
    phases = [np.where(rng.random((n, n)) < 0.5, full, A) for _ in range(5)]
    phases = [np.triu(p, 1) | np.triu(p, 1).T for p in phases]
    switching = 300

    def graph(k):
        return phases[(k // 7) % len(phases)] if k < switching else A

    W = metropolis_weights(A)
    ticks = switching + min(3 * _spectral_steps(W, tol=1e-7) + 100, 6000)
    x, _ = _run_async(graph, v, ticks, 1, 0.0, rng)
    np.testing.assert_allclose(x.sum(), v.sum(), atol=1e-9)
    np.testing.assert_allclose(x[:, 0], v.mean(), atol=1e-5)
