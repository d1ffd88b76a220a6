"""Fast paths give the same results as the general code, bit for bit (hypothesis).

``Path.frame`` of a Python number runs on Python floats and must return exactly what the
array path returns for the same arc length; ``to_plain`` skips its recursion for plain
values and must convert exactly as the general conversion (docs/journal/performance.md, profile of E5.4 (P12))."""

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from copath.paths import circle, ellipse, eight_curve, lemniscate, line, sinusoid, spline
from copath.slots import coordinate_grid, refine_coordinate
from copath.wire.messages import PeerEnvelope, to_plain

PATHS = {
    "lemniscate": lemniscate(2.3),
    "lemniscate rotated": lemniscate(2.0, 0.4, (1.0, -1.0)),
    "eight": eight_curve(1.5, 1.0, -0.7, (2.0, 3.0)),
    "ellipse": ellipse(1.5, 1.0, 0.3, (1.0, 2.0), 0.2),
    "circle": circle(2.0),
    "sinusoid (open)": sinusoid(0.5, 3.0, 10.0, 0.2, (1.0, 1.0)),
    "line (open)": line((1.0, 1.0), 0.5, 5.0),
    "spline (open)": spline([[0, 0], [1, 1], [2, 0], [3, 1]]),
    "spline (closed)": spline([[0, 0], [1, 1], [2, 0], [1, -1]], closed=True),
}


@pytest.mark.parametrize("name", sorted(PATHS))
@settings(max_examples=300, deadline=None)
@given(u=st.floats(min_value=-2.0, max_value=5.0, allow_nan=False))
def test_frame_of_a_number_is_bit_identical_to_the_array_path(name, u):
    """Inside, beyond both ends of open paths and several laps around closed ones."""
    p = PATHS[name]
    s = u * p.length
    fast = p.frame(s)
    general = tuple(float(v[0]) for v in p.frame(np.array([s])))
    assert all(type(v) is float for v in fast)
    assert np.array(fast).tobytes() == np.array(general).tobytes(), (fast, general)


@pytest.mark.parametrize("name", sorted(PATHS))
def test_frame_at_the_ends_and_the_table_nodes(name):
    p = PATHS[name]
    for s in [0.0, -0.0, p.length, 1e-12, p.length - 1e-12, -1e-12, *p._s_tab[:50:7].tolist()]:
        fast = p.frame(s)
        general = tuple(float(v[0]) for v in p.frame(np.array([s])))
        assert np.array(fast).tobytes() == np.array(general).tobytes(), (s, fast, general)
    assert p.frame(np.float64(1.25)) == p.frame(1.25) and p.frame(1) == p.frame(1.0)


def _general(x):
    """The conversion without fast paths (numpy first, then lists, tuples and dicts)."""
    if hasattr(x, "tolist"):
        return x.tolist()
    if isinstance(x, (list, tuple)):
        return [_general(v) for v in x]
    if isinstance(x, dict):
        return {str(k): _general(v) for k, v in x.items()}
    return x


leaf = st.one_of(st.none(), st.booleans(), st.integers(-2**40, 2**40), st.text(max_size=4),
                 st.floats(allow_nan=False, width=64), st.floats(allow_nan=False).map(np.float64),
                 st.integers(-100, 100).map(np.int64),
                 st.lists(st.floats(allow_nan=False), max_size=3).map(np.array))
tree = st.recursive(leaf, lambda ch: st.one_of(
    st.lists(ch, max_size=4), st.lists(ch, max_size=4).map(tuple),
    st.dictionaries(st.one_of(st.text(max_size=3), st.integers(0, 9)), ch, max_size=4)), max_leaves=12)


@settings(max_examples=300, deadline=None)
@given(tree)
def test_to_plain_converts_like_the_general_conversion(x):
    got, want = to_plain(x), _general(x)
    assert msgpack.packb(got, use_bin_type=True) == msgpack.packb(want, use_bin_type=True)
    assert type(got) is type(want)


def test_packed_record_with_numpy_and_tuples_has_plain_fields():
    env = PeerEnvelope("r1", 3, np.float64(0.5), "coord_state", (np.float64(1.0), 2.0),
                       {"s": np.float64(1.5), "sdot": 0.2, "s_d": -0.5, 7: (1, 2)}, None, np.array([0.1, 0.2, 0.0]))
    d = msgpack.unpackb(env.pack())
    assert d["pos"] == [1.0, 2.0] and d["vel"] == [0.1, 0.2, 0.0] and d["payload"]["7"] == [1, 2]
    assert list(d)[:3] == ["sender", "seq", "stamp"] and d["type"] == "peer" and math.isclose(d["stamp"], 0.5)


def _track_reference(path, xy, s0, window, resolution=0.01, extension=5.0):
    """``track_coordinate``'s windowed search from ``s0``, written candidate by candidate (the
    indices wrapped round a closed path, clipped to an open one's table): the grid indices
    before the Newton steps."""
    grid, h, P = coordinate_grid(path, resolution, extension)
    n = len(grid)
    w = max(1, int(np.ceil(window / h)))
    offs = np.arange(-w, w + 1)
    i = int(round(s0 / h)) if path.closed else int(np.clip(round((s0 - grid[0]) / h), 0, n - 1))
    idx = []
    for k in range(len(xy)):
        cand = i + offs
        ci = np.mod(cand, n) if path.closed else np.clip(cand, 0, n - 1)
        d = P[ci] - xy[k]
        j = int(np.argmin(np.einsum("ij,ij->i", d, d)))
        i = int(cand[j]) if path.closed else int(ci[j])
        idx.append(i)
    return np.asarray(idx), h, grid


@pytest.mark.parametrize("name", ["lemniscate", "circle", "sinusoid (open)", "line (open)"])
@pytest.mark.parametrize("window", [0.05, 0.5])
def test_track_coordinate_searches_the_same_candidates_as_one_by_one(name, window):
    """The padded table's slices are the wrapped (closed) or clipped (open) candidates in
    their order: the same nearest sample, ties included (near an open end, clipped
    candidates repeat the end point)."""
    from copath.slots import track_coordinate  # noqa: PLC0415

    p = PATHS[name]
    rng = np.random.default_rng(7)
    s = np.cumsum(rng.uniform(-0.02, 0.06, 300)) - 0.2 * p.length
    xy = np.asarray(p.pos(s)) + rng.normal(0.0, 0.05, (300, 2))
    idx, h, grid = _track_reference(p, xy, float(s[0]), window)
    s0 = idx * h if p.closed else grid[idx]
    got = track_coordinate(p, xy, window=window, s0=float(s[0]))
    # the result is s0 refined by four clipped Newton steps: within the table spacing of s0,
    # and the same as refining s0 directly
    assert np.all(np.abs(got - s0) <= 4 * h + 1e-12)
    assert got.tobytes() == refine_coordinate(p, xy, s0, h).tobytes()


@settings(max_examples=200, deadline=None)
@given(v=st.floats(-3.0, 3.0), w=st.floats(-5.0, 5.0), th=st.floats(-7.0, 7.0))
def test_model_fast_paths_equal_the_array_paths(v, w, th):
    """A unicycle's saturation of a tuple and of an array, and the envelopes' world velocity
    as floats and as an array, agree bit for bit."""
    from copath.models import OmniModel, UnicycleModel, world_velocity, world_velocity_list  # noqa: PLC0415

    m = UnicycleModel(v_max=0.5, omega_max=1.0)
    fast, slow = m.saturate((v, w)), m.saturate(np.array([v, w]))
    assert fast[0].tobytes() == slow[0].tobytes() and fast[1] == slow[1]
    assert m.saturate([v, w])[0].tobytes() == slow[0].tobytes()
    for model, cmd in ((m, fast[0]), (OmniModel(), np.array([v, w, 0.5 * v]))):
        as_list = world_velocity_list(model, th, cmd)
        assert all(type(x) is float for x in as_list)
        assert np.array(as_list).tobytes() == world_velocity(model, th, cmd).tobytes()
        assert world_velocity_list(model, th, cmd.tolist()) == as_list


def test_world_saturates_again_when_a_command_or_a_step_changed_it():
    """``World.saturate_all`` skips a second pass over unchanged commands (a lockstep tick's
    truth, then its step) but not one after a new command or a physics step."""
    from copath.scenario import parse_scenario  # noqa: PLC0415
    from sim.world import World  # noqa: PLC0415

    model = {"type": "unicycle", "v_max": 0.5, "omega_max": 1.0, "a_max": 0.3}
    w = World(parse_scenario({"id": "sat", "run": {"duration_s": 5.0, "dt": 0.1},
                              "robots": [{"name": "r1", "model": model, "pose": [0.0, 0.0, 0.0]}],
                              "controller": {"type": "tests.closed_loop.test_safety:build_silent"}}))
    w.command("r1", [0.5, 0.0])
    w.saturate_all()
    assert w.applied["r1"][0] == pytest.approx(0.03)  # a_max dt from rest
    w.saturate_all()
    assert w.applied["r1"][0] == pytest.approx(0.03)  # idempotent
    w.command("r1", [0.01, 0.0])
    w.saturate_all()
    assert w.applied["r1"][0] == pytest.approx(0.01)  # a new command is saturated again
    w.advance(0.1)
    w.command("r1", [0.5, 0.0])
    w.saturate_all(0.2)
    assert w.applied["r1"][0] == pytest.approx(0.01 + 0.06)  # from the step's command, with the new dt
    w.advance(0.2)
    w.saturate_all()
    assert w.applied["r1"][0] == pytest.approx(0.07 + 0.06)  # after a step, from its command
