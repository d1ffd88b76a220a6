"""``copath bench solve``: solve times of the Chapter 4 MPC controllers versus horizon.

Each controller is built from its scenario file (horizon overridden) and run in a
closed loop (pose <- model.step(pose, saturated command, dt), no noise). The time of
every solve call is measured after a warm-up: the LTV condensing + QP call, or the
NMPC wrapper's solve (parameters, path look-ups and the warm-started SQP). It prints a
table of p50/p99 in milliseconds per controller and horizon and, with ``--json``, an
object ``{controller: {N: {"p50_ms", "p99_ms", "solves", "failures"}}}``. Every case is
built (and JIT-compiled) afresh: the full default run takes several minutes.

For comparison, the dissertation's Table 4.1 (OOQP on the robot's Pentium-M, LTV QP):
0.54 / 1.12 / 2.19 / 9.74 / 29.62 ms at N = 1 / 3 / 5 / 10 / 15.
"""

from __future__ import annotations

import argparse
import json
import logging
import pathlib
import time
from typing import Callable

import numpy as np

from agent.controllers import build_controller
from copath.control import Observation, RobotContext
from copath.scenario import load_scenario

__all__ = ["add_arguments", "run", "CONTROLLERS", "TABLE_4_1_MS"]

logger = logging.getLogger(__name__)

CONFIGS = pathlib.Path(__file__).resolve().parents[3] / "configs"

# name -> (scenario file prefix, attribute holding the solver object)
CONTROLLERS: dict[str, tuple[str, str]] = {
    "ltv_qp": ("e4.3-", "qp"),
    "omni_nmpc_pf": ("e4.2-", "nmpc"),
    "omni_nmpc_tt": ("e4.1-", "nmpc"),
    "unicycle_nmpc": ("e4.4-unicycle-nmpc-combined", "nmpc"),
}
TABLE_4_1_MS = {1: 0.54, 3: 1.12, 5: 2.19, 10: 9.74, 15: 29.62}
"""Table 4.1: LTV QP solve time [ms] on the experiment's computer (OOQP)."""
HORIZONS = (1, 3, 5, 10, 15, 20, 30)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--controllers", nargs="+", choices=sorted(CONTROLLERS), default=list(CONTROLLERS),
                        help="controllers to time (default: all)")
    parser.add_argument("--horizons", type=int, nargs="+", default=list(HORIZONS), help="horizons N")
    parser.add_argument("--solves", type=int, default=500, help="timed solves per case (>= 500 recommended)")
    parser.add_argument("--warmup", type=int, default=50, help="untimed solves before timing")
    parser.add_argument("--no-jit", action="store_true", help="do not JIT-compile the solvers")
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of the table")


def _config(prefix: str) -> pathlib.Path:
    matches = sorted(CONFIGS.glob(f"{prefix}*.toml"))
    if len(matches) != 1:
        raise FileNotFoundError(f"expected one scenario starting with {prefix!r} in configs/, found {len(matches)}")
    return matches[0]


def _timed(obj, times: list[float]) -> None:
    """Replace ``obj.solve`` by a version that appends its wall time [s] to ``times``."""
    inner: Callable = obj.solve

    def solve(*a, **k):
        t0 = time.perf_counter()
        out = inner(*a, **k)
        times.append(time.perf_counter() - t0)
        return out

    obj.solve = solve


def bench_case(name: str, N: int, solves: int, warmup: int, jit: bool = True) -> dict:
    """Closed-loop solve times of controller ``name`` at horizon N."""
    prefix, attr = CONTROLLERS[name]
    sc = load_scenario(_config(prefix))
    spec = sc.robots[0]
    params = {**spec.params, "horizon": max(N, 2) if name == "ltv_qp" else N, "jit": jit}
    ctx = RobotContext(name=spec.name, index=0, model=spec.model, paths=sc.paths, path=spec.path,
                       neighbours=(), robots=(spec.name,), dt=sc.run.dt, params=params)
    ctrl = build_controller(spec.controller, ctx)
    times: list[float] = []
    shadow = None
    if name == "ltv_qp" and N == 1:
        # N = 1 cannot steer y_e (the input reaches it one step later), so the loop runs
        # at N = 2 and an N = 1 QP is timed on the same states (first-step data)
        from agent.controllers.ltv_mpc.controller import LTVPathFollowingQP

        cfg = ctrl.cfg
        shadow = LTVPathFollowingQP(1, ctx.dt, cfg.Q, cfg.R, cfg.qp_solver, jit, name="bench_ltv1")
        inner = ctrl.qp.solve

        def solve(xe, kappa, u_R, lb, ub):
            t0 = time.perf_counter()
            shadow.solve(xe, kappa[:1], u_R[:1], np.ravel(lb)[:3], np.ravel(ub)[:3])
            times.append(time.perf_counter() - t0)
            return inner(xe, kappa, u_R, lb, ub)

        ctrl.qp.solve = solve
    else:
        _timed(getattr(ctrl, attr), times)
    model = spec.model
    pose = np.array(spec.pose, dtype=float)
    dt = sc.run.dt
    failures = 0
    for k in range(warmup + solves):
        res = ctrl.step(Observation(t=k * dt, pose=pose.copy(), dt=dt), [])
        failures += not res.telemetry.get("solver_ok", True)
        cmd, _ = model.saturate(res.command)
        pose = model.step(pose, cmd, dt)
        if k + 1 == warmup:
            times.clear()
    ms = np.asarray(times) * 1e3
    return {"p50_ms": round(float(np.percentile(ms, 50)), 4), "p99_ms": round(float(np.percentile(ms, 99)), 4),
            "solves": int(len(ms)), "failures": int(failures)}


def run(args: argparse.Namespace) -> int:
    logging.getLogger("copath.mpc").setLevel(logging.ERROR)
    results: dict[str, dict[str, dict]] = {}
    for name in args.controllers:
        results[name] = {}
        for N in args.horizons:
            try:
                results[name][str(N)] = bench_case(name, N, args.solves, args.warmup, jit=not args.no_jit)
            except Exception as exc:  # a benchmark reports, it does not crash half-way
                logger.error("bench %s N=%d failed: %s", name, N, exc)
                results[name][str(N)] = {"error": str(exc)}
    if args.json:
        print(json.dumps(results, indent=2))
        return 0 if all("error" not in c for r in results.values() for c in r.values()) else 1
    print(f"closed-loop solve times [ms], {args.solves} warm-started solves per case (p50 / p99)")
    header = f"{'controller':<16}" + "".join(f"{'N=' + str(N):>16}" for N in args.horizons)
    print(header)
    for name, row in results.items():
        cells = []
        for N in args.horizons:
            c = row[str(N)]
            cells.append(f"{'error':>16}" if "error" in c else f"{c['p50_ms']:>7.3f} /{c['p99_ms']:>7.3f}")
        print(f"{name:<16}" + "".join(f"{x:>16}" for x in cells))
    print(f"{'Table 4.1 (QP)':<16}" + "".join(f"{TABLE_4_1_MS.get(N, float('nan')):>16.2f}" for N in args.horizons))
    fails = {f"{n} N={N}": c.get("failures") for n, r in results.items() for N, c in r.items() if c.get("failures")}
    if fails:
        print(f"solver fallbacks during the loops: {fails}")
    return 0 if all("error" not in c for r in results.values() for c in r.values()) else 1


if __name__ == "__main__":  # pragma: no cover
    p = argparse.ArgumentParser(prog="copath bench solve")
    add_arguments(p)
    raise SystemExit(run(p.parse_args()))
