"""``copath envelope``: where a controller breaks, over a grid of delay x loss.

``copath envelope e5.5 --delays 0,100,300,500,700,1000 --losses 0,0.2,0.3,0.5 --seeds 1-3 --inprocess``
runs every (delay, loss) cell of the grid with every seed, through ``copath sweep``
(orchestrator/studies/sweep.py: the same runs, the same figures from the simulator's truth in each
log), and summarises one headline figure per cell: the coordination error after settling
(``coordination_error_max_m``), or the formations completed (``tasks_completed``) for a
task-sequencing team, or another key chosen with ``--metric``. ``--cells 0/0,300/0.3``
runs a list of cells instead of the full grid; ``--set KEY=VALUE`` fixes a setting for every
run (``run.duration_s=120``).

Output (``--out DIR``): ``envelope.csv`` (one row per cell: delay, loss, runs, failed runs,
mean and worst of the headline figure over the seeds, its target, whether every run met
it, and the scenario's targets met over all runs), ``runs.csv`` (one row per run, as
``copath sweep`` writes it), ``summary.txt`` and ``envelope-<metric>.png``: a heat map of
the worst figure over delay x loss, each cell labelled mean/worst, with a tick where every
run met the headline target and a green frame where every run met every target of the
scenario's ``[targets]``. What the built-in controllers reach is in docs/reference/envelope.md.
"""

from __future__ import annotations

import csv
import math
import pathlib
from dataclasses import dataclass
from typing import Callable, Sequence

from copath.config import ConfigError
from copath.grading import AT_MOST, TARGETS, meets, worst

from orchestrator.studies import sweep

__all__ = ["Cell", "parse_cells", "parse_numbers", "grid", "headline_metric", "run_envelope", "cells_of",
           "format_envelope", "write_envelope_csv", "plot_envelope", "HEADLINE_ORDER"]

DELAY, LOSS = "network.delay_ms", "network.loss"

HEADLINE_ORDER = ("tasks_completed", "coordination_error_max_m", "formation_error_max_m", "path_error_max_m")
"""Headline figure of a scenario: the first of these it has a target for (else the first it measures)."""


def parse_numbers(text: str, key: str) -> list[float]:
    """``0,100,300`` -> [0.0, 100.0, 300.0]; every value finite and >= 0."""
    out = []
    for part in str(text).split(","):
        try:
            v = float(part)
        except ValueError:
            v = math.nan
        if not math.isfinite(v) or v < 0:
            raise ConfigError(f"{key} = {text!r} is not allowed; expected comma-separated numbers >= 0, e.g. 0,100,300")
        out.append(v)
    return list(dict.fromkeys(out))


def parse_cells(text: str) -> list[tuple[float, float]]:
    """``0/0,300/0.3,1000/0.5`` -> [(delay_ms, loss), ...]."""
    out = []
    for part in str(text).split(","):
        try:
            d, p = (float(x) for x in part.split("/"))
        except ValueError:
            d = p = math.nan
        if not (math.isfinite(d) and math.isfinite(p) and d >= 0 and 0 <= p <= 1):
            raise ConfigError(f"--cells = {text!r} is not allowed; expected DELAY_MS/LOSS pairs like 0/0,300/0.3 "
                              "(delay >= 0, loss in [0, 1])")
        out.append((d, p))
    return list(dict.fromkeys(out))


def grid(delays: Sequence[float], losses: Sequence[float]) -> list[tuple[float, float]]:
    """Every (delay, loss) pair, delay outermost."""
    for p in losses:
        if not 0 <= p <= 1:
            raise ConfigError(f"--losses = {p} is not allowed; a loss probability is in [0, 1]")
    return [(d, p) for d in delays for p in losses]


def headline_metric(scenario) -> str:
    """The headline figure of a scenario: the first key of :data:`HEADLINE_ORDER` it has a
    target for, else coordination_error_max_m."""
    keys = {t.key for t in scenario.targets}
    for k in HEADLINE_ORDER:
        if k in keys:
            return k
    return "coordination_error_max_m"


@dataclass
class Cell:
    delay_ms: float
    loss: float
    runs: int
    failed: int
    mean: float | None
    worst: float | None
    target: float | None
    """The scenario's threshold on the headline figure (None without one)."""
    met: bool | None
    """Every run met the headline target (None without one)."""
    targets_met: int
    targets_total: int

    @property
    def all_met(self) -> bool:
        return self.targets_total > 0 and self.targets_met == self.targets_total and not self.failed


def cells_of(rows: Sequence[sweep.SweepRow], metric: str, target: float | None) -> list[Cell]:
    """Group the runs by (delay, loss): mean and worst of ``metric`` over the seeds."""
    groups: dict[tuple[float, float], list[sweep.SweepRow]] = {}
    for r in rows:
        groups.setdefault((float(r.setting[DELAY]), float(r.setting[LOSS])), []).append(r)
    out = []
    for (d, p), rs in groups.items():
        vals = [r.figures.get(metric) for r in rs]
        known = [v for v in vals if v is not None]
        met = None if target is None else all(meets(metric, v, target) for v in vals)
        out.append(Cell(d, p, len(rs), sum(not r.ok for r in rs), sum(known) / len(known) if known else None,
                        worst(metric, known) if known else None, target, met,
                        sum(r.targets_met for r in rs), sum(r.targets_total for r in rs)))
    return out


def run_envelope(config: str | pathlib.Path, cells: Sequence[tuple[float, float]], seeds: list[int] | None, *,
                 out_dir: str | pathlib.Path, fixed: Sequence[str] = (), inprocess: bool = False,
                 jobs: int | None = None, wall_timeout_s: float | None = None,
                 on_done: Callable[[sweep.SweepRow, int], None] | None = None) -> list[sweep.SweepRow]:
    """Run every cell with every seed through :func:`orchestrator.studies.sweep.run_sweep` (one sweep
    per delay, its losses as the swept axis); ``fixed`` are ``KEY=VALUE`` settings of every
    run. Writes ``runs.csv`` into ``out_dir``; returns the rows, numbered in order."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    extra = sweep.parse_axes(list(fixed))
    for k, vals in extra:
        if k in (DELAY, LOSS):
            raise ConfigError(f"--set {k} is not allowed in an envelope; the grid sets it (--delays, --losses, --cells)")
        if len(vals) != 1:
            raise ConfigError(f"--set {k} = {vals} is not allowed in an envelope; give one value")
    by_delay: dict[float, list[float]] = {}
    for d, p in cells:
        by_delay.setdefault(d, []).append(p)
    rows: list[sweep.SweepRow] = []
    done = 0

    def count(row: sweep.SweepRow, _n: int) -> None:
        nonlocal done
        done += 1
        if on_done is not None:
            on_done(row, done)

    for i, (d, losses) in enumerate(by_delay.items()):
        axes = [(DELAY, [d]), (LOSS, losses), *extra]
        part = sweep.run_sweep(config, axes, seeds, out_dir=out / f"delay{i:02d}", inprocess=inprocess, jobs=jobs,
                               wall_timeout_s=wall_timeout_s, on_done=count)
        for r in part:
            r.index = len(rows)
            rows.append(r)
    sweep.write_csv(rows, out / "runs.csv")
    return rows


def write_envelope_csv(cells: Sequence[Cell], metric: str, path: pathlib.Path) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["delay_ms", "loss", "runs", "failed", "metric", "mean", "worst", "target", "target_met",
                    "targets_met", "targets_total"])
        for c in cells:
            w.writerow([c.delay_ms, c.loss, c.runs, c.failed, metric, "" if c.mean is None else c.mean,
                        "" if c.worst is None else c.worst, "" if c.target is None else c.target,
                        "" if c.met is None else c.met, c.targets_met, c.targets_total])


def format_envelope(cells: Sequence[Cell], metric: str) -> str:
    """One line per cell: delay, loss, runs, failed, mean/worst of the headline figure,
    its target met in every run, and the scenario's targets met over all runs."""
    head = ["delay ms", "loss", "runs", "failed", f"{metric} mean/worst", "target", "all targets"]
    table = [head]
    for c in cells:
        tgt = "-" if c.met is None else f"{'met' if c.met else 'missed'} ({sweep.format_number(c.target)})"
        table.append([sweep.format_number(c.delay_ms), f"{c.loss:g}", str(c.runs), str(c.failed), f"{sweep.format_number(c.mean)}/{sweep.format_number(c.worst)}",
                      tgt, f"{c.targets_met}/{c.targets_total}" if c.targets_total else "-"])
    widths = [max(len(row[i]) for row in table) for i in range(len(head))]
    lines = ["  ".join(s.rjust(w) for s, w in zip(row, widths)).rstrip() for row in table]
    lines.insert(1, "-" * max(len(line) for line in lines))
    return "\n".join(lines)


def plot_envelope(cells: Sequence[Cell], metric: str, path: pathlib.Path, title: str = "") -> pathlib.Path:
    """Heat map of the worst headline figure over delay (rows) x loss (columns); cells not
    run stay blank. Label mean/worst; a tick where every run met the headline target, a
    green frame where every run met every target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.patches import Rectangle

    delays = sorted({c.delay_ms for c in cells})
    losses = sorted({c.loss for c in cells})
    Z = np.full((len(delays), len(losses)), np.nan)
    for c in cells:
        if c.worst is not None:
            Z[delays.index(c.delay_ms), losses.index(c.loss)] = c.worst
    good_low = TARGETS[metric][1] == AT_MOST
    fig, ax = plt.subplots(figsize=(1.6 + 1.5 * len(losses), 1.4 + 0.8 * len(delays)))
    cmap = plt.get_cmap("viridis" if good_low else "viridis_r").with_extremes(bad="white")
    norm = None
    if good_low and np.nanmin(Z, initial=np.inf) > 0 and np.isfinite(Z).any() and np.nanmax(Z) / np.nanmin(Z) > 20:
        norm = matplotlib.colors.LogNorm()
    im = ax.imshow(np.ma.masked_invalid(Z), cmap=cmap, norm=norm, aspect="auto", origin="lower")
    fig.colorbar(im, ax=ax, label=f"{metric} (worst over seeds)")
    for c in cells:
        i, j = delays.index(c.delay_ms), losses.index(c.loss)
        mark = "" if c.met is None else (" \u2713" if c.met else " \u2717")
        ax.text(j, i, f"{sweep.format_number(c.mean)}/{sweep.format_number(c.worst)}{mark}", ha="center", va="center", fontsize=8,
                color="black", bbox={"facecolor": "white", "alpha": 0.6, "edgecolor": "none", "pad": 1})
        if c.all_met:
            ax.add_patch(Rectangle((j - 0.48, i - 0.48), 0.96, 0.96, fill=False, edgecolor="limegreen", lw=3))
    ax.set_xticks(range(len(losses)), [f"{p:g}" for p in losses])
    ax.set_yticks(range(len(delays)), [sweep.format_number(d) for d in delays])
    ax.set_xlabel("loss probability")
    ax.set_ylabel("delay [ms]")
    tgt = next((c.target for c in cells if c.target is not None), None)
    sub = f"mean/worst; \u2713 every run meets {metric} {TARGETS[metric][1]} {sweep.format_number(tgt)}" if tgt is not None \
        else "mean/worst"
    ax.set_title(f"{title}\n{sub}; green frame: all targets met", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
