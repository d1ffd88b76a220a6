"""``copath sweep``: the product of settings and seeds, one run each, one table and plots.

``copath sweep e5.5 --seeds 1-10 --set network.loss=0,0.1,0.2 --set network.delay_ms=0,100,300``
runs 3 x 3 x 10 = 90 runs of E5.5 and maps the fault envelope of the controller: for every
setting the mean and the worst of each headline figure over the seeds. Each run is a real
fleet (its own router, recorder and processes, kept in its own directory with its log),
or an in-process lockstep run with ``--inprocess``; several run at once where the cores
allow (``--jobs``). Figures come from each run's metrics, computed from the simulator's
truth in its log.

Output (``--out DIR``): ``sweep.csv`` (one row per run: the swept values, seed, outcome,
headline figures, targets met), ``summary.txt`` (what is printed) and
``sweep-<metric>.png`` per headline figure against the swept values.
"""

from __future__ import annotations

import csv
import itertools
import json
import logging
import multiprocessing
import os
import pathlib
import time
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from copath.config import ConfigError
from copath import grading

from orchestrator import api

logger = logging.getLogger(__name__)

__all__ = ["parse_seeds", "parse_axes", "plan", "run_sweep", "summarise", "format_summary", "plot_sweep",
           "SweepRow"]


def parse_seeds(text: str) -> list[int]:
    """``1-10``, ``1,2,5`` or ``3,7-9`` -> a list of seeds."""
    out: list[int] = []
    for part in str(text).split(","):
        part = part.strip()
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise ConfigError(f"--seeds = {text!r} is not allowed; expected seeds like 1-10 or 1,2,5") from None
    return list(dict.fromkeys(out))


def parse_axes(items: Sequence[str]) -> list[tuple[str, list[Any]]]:
    """``--set key=v1,v2,...`` items -> [(key, [values])] in the order given."""
    axes: list[tuple[str, list[Any]]] = []
    for item in items:
        key, text = api.parse_set(item)
        values = api.parse_values(text)
        if not values:
            raise ConfigError(f"--set {key} = {text!r} is not allowed; give at least one value")
        if key in (k for k, _ in axes):
            raise ConfigError(f"--set {key} is not allowed twice; list its values once, comma-separated")
        if key == "run.seed":
            raise ConfigError("--set run.seed is not allowed in a sweep; use --seeds")
        axes.append((key, values))
    return axes


def plan(axes: list[tuple[str, list[Any]]], seeds: list[int] | None) -> list[dict[str, Any]]:
    """The settings of every run: the product of the axes, then of the seeds (innermost)."""
    keys = [k for k, _ in axes]
    out = []
    for combo in itertools.product(*(v for _, v in axes)):
        for seed in seeds or [None]:
            s = dict(zip(keys, combo))
            if seed is not None:
                s["run.seed"] = seed
            out.append(s)
    return out


@dataclass
class SweepRow:
    index: int
    setting: dict[str, Any]
    run_id: str
    ok: bool
    failure: str | None
    figures: dict[str, float | None]
    targets_met: int
    targets_total: int
    wall_s: float


def _label(v: Any) -> str:
    return json.dumps(v) if not isinstance(v, str) else v


def _one(config: str, setting: dict[str, Any], index: int, run_id: str, out_dir: str | None,
         inprocess: bool, wall_timeout_s: float | None) -> dict[str, Any]:
    """One run (in a worker thread or process); returns a plain dict."""
    t0 = time.monotonic()
    try:
        run = api.run(config, setting, inprocess=inprocess, out_dir=out_dir, run_id=run_id,
                      wall_timeout_s=wall_timeout_s)
        results = run.grade()
        return {"ok": run.ok, "failure": None if run.ok else run.reason, "figures": api.headline(run.metrics),
                "met": sum(r.passed for r in results), "total": len(results), "wall": time.monotonic() - t0}
    except Exception as exc:  # one failed run must not end the sweep
        logger.exception("sweep run %d failed", index)
        return {"ok": False, "failure": f"{type(exc).__name__}: {exc}", "figures": dict.fromkeys(api.HEADLINE),
                "met": 0, "total": 0, "wall": time.monotonic() - t0}


def default_jobs(n_robots: int, inprocess: bool) -> int:
    cores = os.cpu_count() or 1
    return max(1, cores if inprocess else cores // (n_robots + 1))


def run_sweep(config: str | pathlib.Path, axes: list[tuple[str, list[Any]]], seeds: list[int] | None, *,
              out_dir: str | pathlib.Path, inprocess: bool = False, jobs: int | None = None,
              wall_timeout_s: float | None = None,
              on_done: Callable[[SweepRow, int], None] | None = None) -> list[SweepRow]:
    """Run every setting of the sweep; write ``sweep.csv`` into ``out_dir``; return the rows."""
    path = api.find_scenario(config)
    settings = plan(axes, seeds)
    base = api.load(path)
    for s in settings:  # every setting is validated before the first run starts
        api.load(path, s)
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = jobs or default_jobs(len(base.robots), inprocess)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    rows: list[SweepRow | None] = [None] * len(settings)
    if inprocess and jobs > 1:  # in-process runs are CPU-bound in Python: one process each
        pool = ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"))
    else:  # a fleet run waits on its own processes: threads suffice
        pool = ThreadPoolExecutor(max_workers=jobs)
    futures: dict[Future, int] = {}
    try:
        for i, s in enumerate(settings):
            rid = f"{base.id}-sweep{stamp}-{i:03d}"
            run_dir = None if inprocess else str(out / f"run{i:03d}")
            futures[pool.submit(_one, str(path), s, i, rid, run_dir, inprocess, wall_timeout_s)] = i
        done = 0
        for f in as_completed(futures):
            i = futures[f]
            r = f.result()
            rid = f"{base.id}-sweep{stamp}-{i:03d}"
            rows[i] = SweepRow(i, settings[i], rid, r["ok"], r["failure"], r["figures"], r["met"], r["total"],
                               r["wall"])
            done += 1
            if on_done is not None:
                on_done(rows[i], done)
    except KeyboardInterrupt:
        # no new run starts; the runs under way end on their own (a fleet tears down its processes)
        pool.shutdown(wait=True, cancel_futures=True)
        write_csv([r for r in rows if r is not None], out / "sweep.csv")
        raise
    pool.shutdown(wait=True)
    final = [r for r in rows if r is not None]
    write_csv(final, out / "sweep.csv")
    return final


def write_csv(rows: list[SweepRow], path: pathlib.Path) -> None:
    keys = list(dict.fromkeys(k for r in rows for k in r.setting))
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["run", "run_id", *keys, "ok", "failure", *api.HEADLINE, "targets_met", "targets_total",
                    "wall_s"])
        for r in rows:
            w.writerow([r.index, r.run_id, *(_label(r.setting.get(k)) for k in keys), r.ok, r.failure or "",
                        *("" if r.figures.get(k) is None else r.figures[k] for k in api.HEADLINE),
                        r.targets_met, r.targets_total, f"{r.wall_s:.2f}"])


def summarise(rows: list[SweepRow]) -> tuple[list[str], list[str], list[dict[str, Any]]]:
    """Group the rows by setting (all swept keys but the seed): mean and worst per figure.

    Returns (setting keys, figure keys with any value, one dict per setting with
    ``setting``, ``runs``, ``failed``, ``targets_met``, ``targets_total``, ``mean``, ``worst``)."""
    swept = list(dict.fromkeys(k for r in rows for k in r.setting if k != "run.seed"))
    skeys = [k for k in swept if len({_label(r.setting.get(k)) for r in rows}) > 1]  # constants are not columns
    fkeys = [k for k in api.HEADLINE if any(r.figures.get(k) is not None for r in rows)]
    groups: dict[tuple, list[SweepRow]] = {}
    for r in rows:
        groups.setdefault(tuple(_label(r.setting.get(k)) for k in skeys), []).append(r)
    out = []
    for g, rs in groups.items():
        mean, worst = {}, {}
        for k in fkeys:
            vals = [r.figures[k] for r in rs if r.figures.get(k) is not None]
            mean[k] = sum(vals) / len(vals) if vals else None
            worst[k] = grading.worst(k, vals) if vals else None
        out.append({"setting": dict(zip(skeys, g)), "runs": len(rs), "failed": sum(not r.ok for r in rs),
                    "targets_met": sum(r.targets_met for r in rs), "targets_total": sum(r.targets_total for r in rs),
                    "mean": mean, "worst": worst})
    return skeys, fkeys, out


def format_number(v: float | None) -> str:
    """A table cell: '-' for None, integers without decimals, else three significant digits."""
    if v is None:
        return "-"
    if float(v).is_integer() and abs(v) < 1e6:
        return str(int(v))
    return f"{v:.3g}"


_SHORT = {"path_error_max_m": "path m", "heading_error_max_rad": "heading rad",
          "coordination_error_max_m": "coord m", "formation_error_max_m": "formation m",
          "min_separation_m": "min sep m", "collisions": "collisions", "min_obstacle_clearance_m": "clearance m",
          "tasks_completed": "tasks", "solve_ms_p99": "solve p99 ms", "missed_ticks": "missed",
          "messages_dropped_by_faults": "dropped"}


def format_summary(rows: list[SweepRow]) -> str:
    """One line per setting: runs, failures, targets met, and mean/worst of each headline
    figure over the seeds (the worst robot's figure for per-robot metrics)."""
    skeys, fkeys, groups = summarise(rows)
    head = [*skeys, "runs", "failed", "targets", *(_SHORT.get(k, k) for k in fkeys)]
    sub = [""] * (len(skeys) + 3) + ["mean/worst"] * len(fkeys)
    table = [head, sub]
    for g in groups:
        tgt = f"{g['targets_met']}/{g['targets_total']}" if g["targets_total"] else "-"
        table.append([*(g["setting"][k] for k in skeys), str(g["runs"]), str(g["failed"]), tgt,
                      *(f"{format_number(g['mean'][k])}/{format_number(g['worst'][k])}" for k in fkeys)])
    widths = [max(len(str(row[i])) for row in table) for i in range(len(head))]
    lines = ["  ".join(str(c).rjust(w) for c, w in zip(row, widths)).rstrip() for row in table]
    lines.insert(2, "-" * max(len(line) for line in lines))
    legend = ", ".join(f"{_SHORT[k]} = {k}" for k in fkeys if k in _SHORT)
    return "\n".join([*lines, f"({legend})"])


def plot_sweep(rows: list[SweepRow], out_dir: str | pathlib.Path,
               thresholds: dict[str, float] | None = None) -> list[pathlib.Path]:
    """One PNG per headline figure: mean over seeds (line) and worst (dashed) against the
    first swept key, one line per value of the other swept keys (the seed if nothing else is swept).
    ``thresholds`` (metric key -> threshold, the scenario's ``[targets]``) draws each figure's
    target as a horizontal red line, labelled with its direction (at most / at least)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    skeys, fkeys, groups = summarise(rows)
    out = pathlib.Path(out_dir)
    files = []
    if skeys:
        xkey, rest = skeys[0], skeys[1:]
    else:  # only seeds were swept: each run against its seed
        xkey, rest = "run.seed", []
        groups = [{"setting": {"run.seed": _label(r.setting.get("run.seed"))}, "mean": r.figures,
                   "worst": r.figures} for r in rows]
    for k in fkeys:
        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        lines: dict[tuple, list] = {}
        for g in groups:
            lines.setdefault(tuple(g["setting"][r] for r in rest), []).append(g)
        for li, (label, gs) in enumerate(lines.items()):
            xs_raw = [g["setting"][xkey] for g in gs]
            try:
                xs = [float(x) for x in xs_raw]
                numeric = True
            except ValueError:
                xs, numeric = list(range(len(xs_raw))), False
            order = sorted(range(len(xs)), key=lambda i: xs[i])
            x = [xs[i] for i in order]
            mean = [gs[i]["mean"].get(k) for i in order]
            worst = [gs[i]["worst"].get(k) for i in order]
            name = ", ".join(f"{r}={v}" for r, v in zip(rest, label)) or "mean"
            color = f"C{li % 10}"
            ax.plot(x, [float("nan") if v is None else v for v in mean], "o-", color=color, label=name)
            if skeys:
                ax.plot(x, [float("nan") if v is None else v for v in worst], "v--", color=color, alpha=0.6,
                        label=f"{name} (worst)" if rest else "worst")
            if not numeric:
                ax.set_xticks(x, [xs_raw[i] for i in order])
        if thresholds and k in thresholds:  # the scenario's target (copath.grading: at most or at least)
            words = "at most" if grading.TARGETS.get(k, ("", grading.AT_MOST))[1] == grading.AT_MOST else "at least"
            ax.axhline(thresholds[k], color="red", lw=1.0, ls=":", label=f"target: {words} {thresholds[k]:g}")
        ax.set_xlabel(xkey)
        ax.set_ylabel(k)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
        ax.set_title(f"{k} over {len(rows)} runs")
        fig.tight_layout()
        f = out / f"sweep-{k}.png"
        fig.savefig(f, dpi=100)
        plt.close(fig)
        files.append(f)
    return files
