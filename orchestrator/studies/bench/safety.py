"""Time the safety filter (``copath.safety``) per call, outside any run.

    python -m orchestrator.studies.bench.safety [--calls 2000] [--neighbours 15] [--json]

For an omni robot and a unicycle with ``--neighbours`` heard robots, it times
:meth:`SafetyFilter.filter` on random poses where the nominal command is safe (the filter
returns it unchanged) and where it is not (the barrier QP is solved with DAQP), and prints
p50 / p99 / max in milliseconds. The QP is built before timing, as the runtime does. The
unicycle is timed with its look-ahead rows and deadlock rule (the default: one neighbour
straight ahead makes the filter solve the QP twice, the second time towards the nominal
turned right) and, as ``unicycle-v``, with ``lookahead_m = 0`` (centre rows only, v only).

``guard/committed`` times one robot's whole step of the filter, :meth:`SafetyGuard.apply`, as in
E5.4: unicycles with acceleration limits and committed plans (``commit_accel_mps2``), the robot
driving an arc and publishing a plan every period (so it keeps ``commit_horizon_s / dt`` tubes),
``--neighbours`` robots driving beside it, each heard every period with its velocity; the
nominal command is safe, so it measures the pass-through path that E5.4 takes at 97 % of its steps.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from copath.models import OmniModel, UnicycleModel
from copath.safety import GuardConfig, Neighbour, SafetyConfig, SafetyFilter, SafetyGuard


def _cases(model, n_nb: int, calls: int, rng: np.random.Generator, close: bool):
    for _ in range(calls):
        pose = np.r_[rng.uniform(-0.1, 0.1, 2), rng.uniform(-np.pi, np.pi)]
        if close:  # one neighbour straight ahead, closing: the QP must act
            d = 2 * model.radius + 0.05
            ahead = pose[:2] + d * np.array([np.cos(pose[2]), np.sin(pose[2])])
            nbrs = [Neighbour(tuple(ahead), 0.1, model.radius, 0.5)]
        else:
            nbrs = []
        while len(nbrs) < n_nb:
            p = rng.uniform(-4, 4, 2)
            if np.hypot(*(p - pose[:2])) > 1.5:
                nbrs.append(Neighbour(tuple(p), 0.1, model.radius, 0.5))
        nominal = np.r_[0.4, np.zeros(model.command_size - 1)]
        yield pose, nominal, nbrs


def bench(calls: int = 2000, neighbours: int = 15, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    out = {}
    on = SafetyConfig(enabled=True)
    cases = ((OmniModel(), 0.05, on, "omni"), (UnicycleModel(), 0.1, on, "unicycle"),
             (UnicycleModel(), 0.1, SafetyConfig(enabled=True, lookahead_m=0.0), "unicycle-v"))
    for model, dt, cfg, label in cases:
        f = SafetyFilter(cfg, model, dt, capacity=2 * neighbours)  # room for look-ahead rows
        for close in (False, True):
            times = []
            active = 0
            for pose, nominal, nbrs in _cases(model, neighbours, calls, rng, close):
                t0 = time.perf_counter()
                res = f.filter(pose, nominal, nbrs)
                times.append((time.perf_counter() - t0) * 1e3)
                active += res.active
            ms = np.array(times)
            out[f"{label}/{'qp' if close else 'pass'}"] = {
                "p50_ms": round(float(np.percentile(ms, 50)), 4),
                "p99_ms": round(float(np.percentile(ms, 99)), 4),
                "max_ms": round(float(ms.max()), 4),
                "active": int(active),
                "calls": calls,
            }
    out["guard/committed"] = _guard(calls, neighbours)
    return out


def _guard(calls: int, neighbours: int) -> dict:
    """Time :meth:`SafetyGuard.apply` per robot step with committed plans (see the module docstring)."""
    dt, v, w = 0.1, 0.2, 0.1
    cfg = SafetyConfig(enabled=True, accel_max_mps2=0.5, commit_accel_mps2=0.1)
    names = [f"r{i}" for i in range(neighbours + 1)]
    models = {n: UnicycleModel(a_max=0.3, alpha_max=1.0) for n in names}
    guard = SafetyGuard(GuardConfig(safety=cfg, name=names[0], models=models, dt=dt))
    times, active = [], 0
    warm = int(cfg.commit_horizon_s / dt) + 1
    for k in range(calls + warm):
        now = k * dt
        th = w * now
        heading = (math.cos(th), math.sin(th))
        x, y = (v / w) * math.sin(th), (v / w) * (1.0 - math.cos(th))  # an arc of radius v / w
        vel = (v * heading[0], v * heading[1], w)
        for i, n in enumerate(names[1:], start=1):  # the others beside it, 1 m apart, heard one period ago
            r = v / w + i
            guard.hear(n, (r * math.sin(w * (now - dt)), v / w - r * math.cos(w * (now - dt))), now - dt,
                       (w * r * math.cos(w * (now - dt)), w * r * math.sin(w * (now - dt)), w))
        t0 = time.perf_counter()
        res = guard.apply((x, y, th), [v, w], now)
        if k >= warm:
            times.append((time.perf_counter() - t0) * 1e3)
            active += res.active
        guard.published(now, (x, y), vel)
    ms = np.array(times)
    return {"p50_ms": round(float(np.percentile(ms, 50)), 4), "p99_ms": round(float(np.percentile(ms, 99)), 4),
            "max_ms": round(float(ms.max()), 4), "active": int(active), "calls": calls}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=2000, help="timed calls per case")
    parser.add_argument("--neighbours", type=int, default=15, help="heard robots per call")
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of the table")
    args = parser.parse_args(argv)
    res = bench(args.calls, args.neighbours)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    print(f"{'case':<16}{'p50 ms':>10}{'p99 ms':>10}{'max ms':>10}{'QP solved':>12}")
    for k, v in res.items():
        print(f"{k:<16}{v['p50_ms']:>10.4f}{v['p99_ms']:>10.4f}{v['max_ms']:>10.4f}{v['active']:>7}/{v['calls']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
