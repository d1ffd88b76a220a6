"""``copath bench secure``: what secure mode costs a lockstep fleet (docs/reference/security.md).

Runs a scenario as a fleet over Zenoh in lockstep, alternately with secure mode off and
on (``run.secure``: per-run user/password authentication and access control on the run's
router), ``--reps`` times each, and prints the lockstep speed of each mode: simulated
seconds per wall second between the first and the last recorded truth (start-up left
out), and the median ratio. Secure mode is the default when it costs at most 10 %.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import tempfile
from typing import Any

from orchestrator.studies.bench.harness import emit, print_table

__all__ = ["add_arguments", "run", "measure"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="e5.5", help="bundled stem, experiment id or file [e5.5]")
    parser.add_argument("--duration", type=float, metavar="S", help="simulated seconds (default: the scenario's)")
    parser.add_argument("--reps", type=int, default=3, help="runs of each mode [3]")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


def _speed(log_path: pathlib.Path) -> tuple[float, int]:
    """(simulated s per wall s between the first and last truth, ticks)."""
    from orchestrator.log.mcap import iter_raw  # noqa: PLC0415

    times = [t for t, key, _ in iter_raw(log_path) if key.endswith("/sim/truth")]
    if len(times) < 2:
        return float("nan"), len(times)
    return len(times) / ((times[-1] - times[0]) / 1e9), len(times)


def measure(scenario_ref: str, duration_s: float | None, reps: int) -> dict[str, Any]:
    from orchestrator import api  # noqa: PLC0415
    from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet  # noqa: PLC0415

    overrides = {"run.clock": "lockstep"} | ({"run.duration_s": duration_s} if duration_s else {})
    scenario = api.load(scenario_ref, overrides)
    rows = []
    with tempfile.TemporaryDirectory(prefix="copath-bench-secure-") as tmp:
        for i in range(reps):
            for secure in (False, True):
                rid = new_run_id(scenario.id)
                out = pathlib.Path(tmp) / rid
                res = run_fleet(scenario, RunOptions(out_dir=out, run_id=rid, progress=False, secure=secure))
                ticks_per_s, ticks = _speed(out / "run.mcap")
                rows.append({"rep": i + 1, "secure": secure, "ok": res.ok, "ticks": ticks,
                             "ticks_per_s": ticks_per_s, "rejected": res.metrics["fleet"].get("messages_rejected")})
    med = {s: statistics.median(r["ticks_per_s"] for r in rows if r["secure"] is s) for s in (False, True)}
    return {"scenario": scenario.id, "runs": rows, "ticks_per_s_open": med[False], "ticks_per_s_secure": med[True],
            "cost": 1.0 - med[True] / med[False]}


def run(args: argparse.Namespace) -> int:
    result = measure(args.scenario, args.duration, args.reps)

    def table(r: dict[str, Any]) -> None:
        print_table(r["runs"], [("rep", "rep", "d"), ("secure", "secure", ""), ("ok", "ok", ""),
                                ("ticks", "ticks", "d"), ("ticks_per_s", "ticks/s", ".1f")])
        print(f"median lockstep speed: open {r['ticks_per_s_open']:.1f} ticks/s, secure "
              f"{r['ticks_per_s_secure']:.1f} ticks/s; secure mode costs {100 * r['cost']:.1f} %")

    emit(args, result, table)
    return 0 if all(r["ok"] for r in result["runs"]) else 1
