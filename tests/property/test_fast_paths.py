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
