"""The controller kit (copath.control): inbox, path projection, path table, model limits,
solver options. Each piece replaces copies that the built-in controllers used to carry."""

import math
import os

import numpy as np
import pytest

from copath.control import LatestMessages, Observation, PathTable, PeerMessage, RobotContext, VirtualVehicle
from copath.models import OmniModel, UnicycleModel, rotation_speed_limit
from copath.paths import circle, eight_curve, lemniscate, line, sinusoid
from tests.conftest import REPO


def _msg(sender, stamp, kind="k", age=0.1, **payload):
    return PeerMessage(sender, kind, stamp, age, payload, position=(stamp, 0.0))


# -- LatestMessages -------------------------------------------------------------------


def test_inbox_keeps_the_newest_message_per_sender_and_kind():
    box = LatestMessages()
    new = box.update([_msg("a", 1.0, v=1), _msg("a", 2.0, v=2), _msg("b", 1.5, v=3),
                      _msg("a", 1.5, kind="other", v=4)], t=2.1)
    assert len(new) == 4 and len(box) == 3
    assert box.get("a", "k").payload["v"] == 2
    assert box.get("a", "other").payload["v"] == 4
    assert list(box.of_kind("k")) == ["a", "b"]


def test_inbox_ignores_late_reordered_and_duplicated_messages():
    box = LatestMessages()
    box.update([_msg("a", 2.0, v=2)], t=2.1)
    new = box.update([_msg("a", 1.0, v=1), _msg("a", 2.0, v=99)], t=2.2)  # older, then a duplicate stamp
    assert new == []
    got = box.get("a", "k")
    assert got.payload["v"] == 2 and got.received_at == 2.1
    assert box.update([_msg("a", 2.5, v=3)], t=2.6)[0].payload["v"] == 3


def test_inbox_filters_kinds_senders_and_unusable_payloads():
    box = LatestMessages(kinds=("k",), senders=("a", "b"), accept=lambda m: m.payload.get("ok", True))
    box.update([_msg("a", 1.0), _msg("c", 1.0), _msg("b", 1.0, kind="x")], t=1.0)
    assert ("a", "k") in box and len(box) == 1
    box.update([_msg("a", 2.0, ok=False)], t=2.0)  # newer but unusable: the old one stays
    assert box.get("a", "k").stamp == 1.0


def test_inbox_decodes_each_newer_message_once_and_keeps_the_last_decodable():
    calls = []

    def decode(m):
        calls.append(m.stamp)
        return 2 * m.payload["v"]  # a KeyError when v is missing: the message is unusable

    box = LatestMessages(decode=decode)
    box.update([_msg("a", 1.0, v=1), _msg("a", 0.5, v=7)], t=1.0)  # the older copy is never decoded
    assert box.get("a", "k").value == 2 and calls == [1.0]
    box.update([_msg("a", 2.0)], t=2.0)  # newer but undecodable: the old value stays
    assert box.get("a", "k").value == 2 and box.get("a", "k").stamp == 1.0
    box.update([_msg("a", 3.0, v=5)], t=3.0)
    assert box.get("a", "k").value == 10 and calls == [1.0, 2.0, 3.0]


def test_inbox_ages_and_freshness():
    box = LatestMessages()
    box.update([_msg("a", 1.0, age=0.25), _msg("b", 3.0, age=0.05)], t=3.0)
    a = box.get("a", "k")
    assert a.age(4.0) == pytest.approx(0.25 + 1.0)  # age at delivery plus time held
    assert a.since_stamp(4.0) == pytest.approx(3.0)
    assert list(box.fresh("k", 4.0, max_age=2.0)) == ["b"]
    assert list(box.fresh("k", 4.0, max_age=2.0, by="receipt")) == ["a", "b"]
    assert list(box.fresh("k", 4.0, max_age=1.1, by="age")) == ["b"]
    with pytest.raises(ValueError, match="by = 'x' is not allowed"):
        box.fresh("k", 4.0, 1.0, by="x")
    box.forget(sender="a")
    assert list(box.of_kind("k")) == ["b"]
    box.forget()
    assert len(box) == 0


# -- projection -----------------------------------------------------------------------


@pytest.mark.parametrize("make", [eight_curve, lemniscate, lambda: sinusoid(0.3, 2.0, 6.0)])
def test_projection_finds_the_nearest_path_point(make):
    path = make()
    rng = np.random.default_rng(1)
    for s_true in rng.uniform(0.05, path.length - 0.05, 10):
        th = path.theta(s_true)
        d = rng.uniform(-0.05, 0.05)  # small normal offset: the foot point is s_true
        p = path.pos(s_true) + d * np.array([-math.sin(th), math.cos(th)])
        s = path.project(p)
        assert path.wrap(s) == pytest.approx(s_true, abs=1e-6)
        # a whole pose is accepted too (only x, y are used)
        assert path.project([*p, 1.0]) == pytest.approx(s)


def test_projection_near_a_guess_stays_on_its_branch_at_a_self_crossing():
    path = lemniscate()
    s = np.linspace(0.0, path.length, 4001)
    xy = path.pos(s)
    # the lemniscate crosses itself at the origin: two arc lengths share that point
    near = s[np.hypot(xy[:, 0], xy[:, 1]) < 1e-3]
    s_a = float(near[0])
    s_b = float([v for v in near if abs(v - s_a) > 1.0][0])
    for s_guess in (s_a, s_b):
        along = np.linspace(s_guess - 0.1, s_guess + 0.1, 9)
        got = [path.project(path.pos(v), s_guess=v - 0.01, window=0.2) for v in along]
        np.testing.assert_allclose(got, along, atol=1e-6)


# -- path table -----------------------------------------------------------------------


@pytest.mark.parametrize("make", [eight_curve, lambda: line((0.0, 0.0), 0.3, 4.0)])
def test_path_table_matches_the_curve(make):
    path = make()
    table = path.table()
    assert path.table() is table and isinstance(table, PathTable)
    s = np.linspace(-0.5 if not path.closed else 0.0, path.length + 0.5, 777)
    x, y, th, k = path.frame(s)
    g = table(s)
    np.testing.assert_allclose(g[0], x, atol=1e-6)
    np.testing.assert_allclose(g[1], y, atol=1e-6)
    np.testing.assert_allclose(g[2], th, atol=1e-5)
    np.testing.assert_allclose(g[3], k, atol=2e-3)
    np.testing.assert_allclose(table.pos(s), path.pos(s), atol=1e-6)
    np.testing.assert_allclose(table.theta(s), th, atol=1e-5)
    assert table.frame(1.0) == pytest.approx(path.frame(1.0), abs=2e-3)


def test_path_table_theta_grows_by_the_winding_per_lap():
    path = lemniscate()  # winding number 0: theta returns after a lap
    table = path.table()
    assert table.theta(1.0 + path.length) == pytest.approx(table.theta(1.0), abs=1e-9)
    circle_like = circle(1.0)
    t2 = circle_like.table()
    lap = 2 * math.pi * circle_like.winding
    assert circle_like.winding == 1
    assert t2.theta(0.5 + circle_like.length) == pytest.approx(t2.theta(0.5) + lap, abs=1e-9)


# -- model limits ---------------------------------------------------------------------


def test_omni_limits_are_one_line_and_its_inverse():
    m = OmniModel()
    omega = np.array([0.0, 1.0, 3.0, 5.0])
    np.testing.assert_allclose(m.max_speed(omega), rotation_speed_limit(omega), atol=0)
    np.testing.assert_allclose(m.max_rotation(m.max_speed(omega)), omega, atol=1e-12)  # inverse
    np.testing.assert_allclose(m.max_rotation([0.4, 1.0, 1.315]), [7.692, 4.615, 3.0], atol=1e-3)
    # turning with the tangent: u = r(kappa u)
    for kappa in (0.0, 0.5, 2.0):
        u = float(m.max_tangent_speed(kappa))
        assert u == pytest.approx(float(m.max_speed(kappa * u)))


def test_omni_wheel_saturation_keeps_the_direction():
    m = OmniModel()
    q = np.array([3.8, -1.0, 0.5])
    sat = m.saturate_wheels(q)
    assert np.max(np.abs(sat)) == pytest.approx(m.qdot_max)
    assert np.cross(sat, q) == pytest.approx(np.zeros(3), abs=1e-12)
    small = np.array([0.1, -0.2, 0.3])
    np.testing.assert_array_equal(m.saturate_wheels(small), small)


# -- solver options -------------------------------------------------------------------


def test_one_solver_options_table():
    mpc = pytest.importorskip("copath.mpc")
    for name in mpc.QP_SOLVERS + ("daqp",):
        opts = mpc.qp_options(name)
        assert opts["error_on_fail"] is False
    a = mpc.qp_options("osqp", warm_start_primal=True)
    a["osqp"]["verbose"] = True  # a copy: the table is not changed
    assert mpc.QP_OPTIONS["osqp"]["osqp"]["verbose"] is False and "warm_start_primal" not in mpc.QP_OPTIONS["osqp"]
    with pytest.raises(ValueError, match="qp_solver = 'none' is not allowed"):
        mpc.qp_options("none")
    assert mpc.jit_options(("-O1",))["jit_options"]["flags"] == ["-O1"]


# -- virtual vehicle ------------------------------------------------------------------


def test_virtual_vehicle_holds_its_speed_over_the_actual_step_times():
    v = VirtualVehicle()
    assert not v.started
    with pytest.raises(ValueError, match="start"):
        v.advance(0.0)
    v.start(1.0)
    assert v.advance(0.0) == 1.0  # nothing held yet
    v.hold(0.0, 0.5)
    assert v.advance(0.3) == pytest.approx(1.15)  # a late step: 0.3 s, not the nominal period
    v.hold(0.3, 0.2)
    assert v.advance(0.2) == pytest.approx(1.15)  # never backwards in time
    assert v.advance(0.8) == pytest.approx(1.15 + 0.2 * 0.5)
    assert v.advance(0.8) == pytest.approx(1.15 + 0.2 * 0.5)  # advancing twice moves once
    assert VirtualVehicle(2).s == 2.0 and VirtualVehicle(2).started


# -- the Chapter 6 controller in phases -------------------------------------------------


def _state(obj) -> set[str]:
    return set(vars(obj))


def test_roles_phases_keep_their_state_in_init_and_three_robots_form_a_triangle():
    """Three roles controllers exchanging their broadcasts (delivered one step later) agree
    on the placement, take distinct positions and reach them; no phase object gains an
    attribute after __init__ (the state of every phase is declared up front)."""
    from agent.controllers.roles.controller import RolesController

    names = ("a", "b", "c")
    tri = [[0.0, 0.6], [-0.5, -0.3], [0.5, -0.3]]
    model = UnicycleModel(v_max=0.5, omega_max=1.0)
    ctls = {n: RolesController(RobotContext(name=n, index=i, model=model, paths={}, path=None, neighbours=(),
                                            robots=names, dt=0.1, params={"formations": [tri]}))
            for i, n in enumerate(names)}
    poses = {"a": np.array([-1.5, 0.2, 0.0]), "b": np.array([1.4, 1.0, 2.0]), "c": np.array([0.3, -1.6, 1.0])}
    before = {n: _state(c) for n, c in ctls.items()}
    pending: list = []
    for k in range(600):
        t = 0.1 * k
        delivered, pending = pending, []
        for n, c in ctls.items():
            inbox = [m for m in delivered if m.sender != n]
            res = c.step(Observation(t=t, pose=poses[n], dt=0.1), inbox)
            pending += [PeerMessage(n, o.kind, t, 0.1, o.payload, position=tuple(poses[n][:2])) for o in res.messages]
            poses[n] = model.step(poses[n], res.command, 0.1)
        if k == 0:
            phase_state = {n: {ph: _state(getattr(c, ph)) for ph in ("peers", "tasks", "agreement", "roles", "motion")}
                           for n, c in ctls.items()}
    for n, c in ctls.items():
        assert _state(c) == before[n]
        for ph, attrs in phase_state[n].items():
            assert _state(getattr(c, ph)) == attrs, (n, ph)
    claims = {n: c.roles.position for n, c in ctls.items()}
    assert sorted(claims.values()) == [0, 1, 2]
    for n, c in ctls.items():
        assert c.tasks.done
        assert np.hypot(*(c.roles.targets[claims[n]] - poses[n][:2])) < 2 * c.cfg.arrive_tol


# -- a family declares itself on its factory (issue 23) --------------------------------------


def test_resolving_every_builtin_name_loads_no_law_and_registers_each_familys_payloads():
    """A family's package declares its factories from light modules (config, payloads,
    geometry, done rule); resolving a name loads no law and no CasADi, in a fresh process,
    and registers the family's message schemas with the wire."""
    import subprocess
    import sys

    code = ("import sys\nfrom agent.controllers import CONTROLLERS, resolve_controller\n"
            "from copath.wire.payloads import PAYLOADS\n"
            "fs = {n: resolve_controller(n) for n in CONTROLLERS}\n"
            "laws = sorted(m for m in sys.modules if m.startswith('agent.controllers.') and m.endswith('.controller'))\n"
            "print(laws, 'casadi' in sys.modules, sorted(PAYLOADS), "
            "sorted(n for n, f in fs.items() if f.geometry), sorted(n for n, f in fs.items() if f.tasks), "
            "sorted(n for n, f in fs.items() if f.handles_cut_off), sorted(n for n, f in fs.items() if f.handles_obstacles))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[0] == (
        "[] False ['assumed_traj', 'coord_state', 'follower_status', 'formation_state', 'hetero_cmd', "
        "'hetero_report', 'leader_plan', 'role_state'] ['consensus', 'dmpc', 'follower_nmpc', "
        "'formation_switching', 'hetero_follower', 'hetero_leader', 'leader_nmpc'] ['roles'] ['roles'] "
        "['unicycle_nmpc']")


def test_a_factory_takes_only_known_declarations_and_one_schema_per_kind():
    from copath.control import controller
    from copath.wire.payloads import register_payloads

    with pytest.raises(TypeError, match="unknown declarations"):
        controller(geometyr=None)
    register_payloads({"test_kind_x": {"a": "float"}})
    register_payloads({"test_kind_x": {"a": "float"}})  # the same again: fine
    with pytest.raises(ValueError, match="registered twice"):
        register_payloads({"test_kind_x": {"a": "int"}})


def test_a_deferred_declaration_imports_its_function_at_its_first_call(tmp_path, monkeypatch):
    import sys

    from copath.control import deferred

    (tmp_path / "late_geometry.py").write_text("CALLS = []\ndef geo(s):\n    CALLS.append(s)\n    return s * 2\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    d = deferred("late_geometry:geo")
    assert "late_geometry" not in sys.modules  # declaring imports nothing
    assert d == deferred("late_geometry:geo") and len({d, deferred("late_geometry:geo")}) == 1
    assert d != deferred("late_geometry:other")
    assert d(21) == 42 and sys.modules["late_geometry"].CALLS == [21]
    monkeypatch.delitem(sys.modules, "late_geometry")
