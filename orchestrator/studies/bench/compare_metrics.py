"""Quality metrics unchanged? Run every bundled scenario in one process and compare key by key.

    copath bench compare-metrics run OUT [--scenarios STEM ...]   # metrics of this checkout into OUT
    copath bench compare-metrics compare BEFORE AFTER [--rtol 1e-9] [--atol 1e-12]

(or ``python -m orchestrator.studies.bench.compare_metrics`` with the same arguments).

``run`` writes ``OUT/<stem>/metrics.json`` for every ``configs/*.toml`` (``copath run
<cfg> --inprocess --no-plots -q``), one scenario at a time. Run it on the code before a
change and on the code after, then ``compare``: every key of ``metrics.json`` must match,
except the timing keys (wall time, solve and filter times, run id: they depend on the
machine, not on what the robots did). Numbers match when equal within ``--rtol``/``--atol``
(default: equal to 1e-9 relative, for a change that reorders floating-point operations;
``--rtol 0 --atol 0`` asks for identity). Exit 1 and a list of the keys that differ
otherwise. Used for docs/reference/performance.md (against IR-SIM, P15).
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import subprocess
import sys
import time
from typing import Any, Iterator

TIMING = ("wall_time_s", "run_id", "solve_ms_p50", "solve_ms_p99", "safety_ms_p50", "safety_ms_p99",
          "deadline_misses", "deadline_miss_rate", "physics_overruns", "realtime_periods")
"""Keys that depend on the machine and its load, not on the run's outcome (any nesting level)."""

ROOT = pathlib.Path(__file__).resolve().parents[3]


def flatten(d: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(dotted key, leaf) of a metrics document; timing keys left out."""
    if isinstance(d, dict):
        for k, v in d.items():
            if k in TIMING or k.endswith("_ms_p50") or k.endswith("_ms_p99") or k.endswith("_wall_s"):
                continue
            yield from flatten(v, f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from flatten(v, f"{prefix}[{i}]")
    else:
        yield prefix, d


def same(a: Any, b: Any, rtol: float, atol: float) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return a == b
    if math.isnan(a) and math.isnan(b):
        return True
    return math.isclose(a, b, rel_tol=rtol, abs_tol=atol)


def compare(before: pathlib.Path, after: pathlib.Path, rtol: float, atol: float) -> list[str]:
    """Differences between the ``metrics.json`` files of two result directories."""
    out = []
    stems = sorted({p.parent.name for p in before.glob("*/metrics.json")} | {p.parent.name for p in after.glob("*/metrics.json")})
    for stem in stems:
        fa, fb = before / stem / "metrics.json", after / stem / "metrics.json"
        if not fa.is_file() or not fb.is_file():
            out.append(f"{stem}: metrics.json missing in {'before' if not fa.is_file() else 'after'}")
            continue
        a, b = dict(flatten(json.loads(fa.read_text()))), dict(flatten(json.loads(fb.read_text())))
        for key in sorted(set(a) | set(b)):
            if key not in a or key not in b:
                out.append(f"{stem}: {key} only in {'after' if key not in a else 'before'}")
            elif not same(a[key], b[key], rtol, atol):
                out.append(f"{stem}: {key}: {a[key]!r} -> {b[key]!r}")
    return out


def run_all(out: pathlib.Path, stems: list[str] | None) -> int:
    out.mkdir(parents=True, exist_ok=True)
    failed = 0
    for cfg in sorted((ROOT / "configs").glob("*.toml")):
        if stems and cfg.stem not in stems:
            continue
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "orchestrator.cli", "run", str(cfg), "--inprocess", "--no-plots", "-q",
                            "--out", str(out / cfg.stem)], cwd=ROOT, capture_output=True, text=True)
        ok = (out / cfg.stem / "metrics.json").is_file()
        failed += not ok
        print(f"{cfg.stem}: {'ok' if ok else 'FAILED (exit ' + str(r.returncode) + ')'} {time.perf_counter() - t0:.1f} s",
              flush=True)
    return 1 if failed else 0


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``copath bench compare-metrics`` (and ``python -m orchestrator.studies.bench.compare_metrics``)."""
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("run", help="run every bundled scenario in one process, metrics into OUT")
    r.add_argument("out", type=pathlib.Path)
    r.add_argument("--scenarios", nargs="+", metavar="STEM", help="only these file stems")
    c = sub.add_parser("compare", help="compare two result directories key by key")
    c.add_argument("before", type=pathlib.Path)
    c.add_argument("after", type=pathlib.Path)
    c.add_argument("--rtol", type=float, default=1e-9)
    c.add_argument("--atol", type=float, default=1e-12)


def run(args: argparse.Namespace) -> int:
    """``run``: 0 when every scenario ran; ``compare``: 0 when nothing differs, else 1."""
    if args.what == "run":
        unknown = sorted(set(args.scenarios or ()) - {c.stem for c in (ROOT / "configs").glob("*.toml")})
        if unknown:
            print(f"--scenarios = {unknown[0]!r} is not allowed; allowed: the stems of configs/*.toml "
                  "(copath scenarios lists them)", file=sys.stderr)
            return 2
        return run_all(args.out, args.scenarios)
    for name in ("before", "after"):
        d = getattr(args, name)
        if not d.is_dir():
            print(f"{name} = {str(d)!r} is not allowed; must be a directory of <stem>/metrics.json", file=sys.stderr)
            return 2
    diffs = compare(args.before, args.after, args.rtol, args.atol)
    for d in diffs:
        print(d)
    n = len(list(args.before.glob("*/metrics.json")))
    print(f"{n} scenarios compared, {len(diffs)} differences (rtol {args.rtol:g}, atol {args.atol:g}; timing keys left out)")
    return 1 if diffs else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m orchestrator.studies.bench.compare_metrics",
                                description=__doc__.split("\n")[0])
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
