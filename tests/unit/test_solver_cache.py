"""The on-disk solver cache: a JIT-compiled solver is compiled once and loaded after that,
keyed by the problem's structure and numbers and the solver options."""

from __future__ import annotations

import shutil

import casadi as ca
import numpy as np
import pytest

from copath import solver_cache
from copath.mpc import OCP, MPCSolver, SolverConfig, jit_available


def _ocp(weight: float = 0.1, name: str = "cache_test") -> OCP:
    return OCP(nx=2, nu=1, N=8, dt=0.1, dynamics=lambda x, u, p: ca.vertcat(x[1], u[0]),
               stage_residual=lambda x, u, p: ca.vertcat(x[0], weight * u[0]),
               terminal_residual=lambda x, p: x, u_lb=[-1.0], u_ub=[1.0], name=name)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("COPATH_SOLVER_CACHE", str(tmp_path))
    monkeypatch.setattr(solver_cache, "stats", {"hits": 0, "misses": 0, "errors": 0})
    return tmp_path


@pytest.mark.skipif(not jit_available(), reason="no working C compiler for CasADi's JIT")
def test_a_solver_is_compiled_once_then_loaded_with_the_same_answers(cache):
    first = MPCSolver(_ocp(), SolverConfig(jit=True)).solve([1.0, 0.0])
    assert solver_cache.stats == {"hits": 0, "misses": 1, "errors": 0}
    files = sorted(p.name for p in cache.glob("nlpsol-*.casadi"))
    assert len(files) == 1
    again = MPCSolver(_ocp(name="another_robot"), SolverConfig(jit=True)).solve([1.0, 0.0])
    assert solver_cache.stats["hits"] == 1 and solver_cache.stats["misses"] == 1  # same structure: shared
    np.testing.assert_array_equal(first.u, again.u)
    # other numbers in the problem, or other options: another entry
    MPCSolver(_ocp(weight=0.2), SolverConfig(jit=True))
    MPCSolver(_ocp(), SolverConfig(jit=True, max_iter=7))
    assert solver_cache.stats["misses"] == 3 and len(list(cache.glob("nlpsol-*.casadi"))) == 3


@pytest.mark.skipif(not jit_available(), reason="no working C compiler for CasADi's JIT")
def test_the_qp_solvers_options_are_part_of_the_key(cache, monkeypatch):
    """The saved solver carries its QP solver's options (:data:`copath.mpc.QP_OPTIONS`), which
    the config does not name: a change to them builds a new entry instead of loading the old
    solver (a cap on qrqp's iterations was once invisible on a machine with a warm cache)."""
    from copath import mpc

    MPCSolver(_ocp(), SolverConfig(jit=True))
    monkeypatch.setitem(mpc.QP_OPTIONS, "qrqp", {**mpc.QP_OPTIONS["qrqp"], "max_iter": 7})
    MPCSolver(_ocp(), SolverConfig(jit=True))
    assert solver_cache.stats["misses"] == 2 and len(list(cache.glob("nlpsol-*.casadi"))) == 2


@pytest.mark.skipif(not jit_available(), reason="no working C compiler for CasADi's JIT")
def test_a_damaged_cache_file_is_rebuilt(cache):
    MPCSolver(_ocp(), SolverConfig(jit=True))
    (path,) = cache.glob("nlpsol-*.casadi")
    path.write_bytes(b"not a casadi function")
    res = MPCSolver(_ocp(), SolverConfig(jit=True)).solve([1.0, 0.0])
    assert res.ok and solver_cache.stats["errors"] >= 1 and solver_cache.stats["misses"] == 2
    assert ca.Function.load(str(path)).n_in() > 0  # replaced by a good one


def test_the_cache_can_be_switched_off(monkeypatch):
    monkeypatch.setenv("COPATH_SOLVER_CACHE", "off")
    assert solver_cache.cache_dir() is None
    built = []
    assert solver_cache.cached_function("x", "k", lambda: built.append(1) or "fn") == "fn" and built == [1]


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler on this machine")
def test_the_jit_probe_works_on_an_empty_cache_and_leaves_nothing_in_the_working_directory(
        tmp_path, monkeypatch):
    # a fresh machine: no probe cached yet (its options used to fail CasADi's type check,
    # and a probe cached by an older build hid that), started from a folder of the user's
    import copath.mpc as mpc

    monkeypatch.setenv("COPATH_SOLVER_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(mpc, "_JIT_OK", None)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert mpc.jit_available()
    MPCSolver(_ocp(name="cwd_test"), SolverConfig(jit=True)).solve([1.0, 0.0])
    assert list(work.iterdir()) == []
