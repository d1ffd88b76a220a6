"""``copath plot``: figures of a run drawn from its log alone (matplotlib, Agg).

:func:`plot_run` reads ``run.mcap`` (records and the recorded scenario) and writes one PNG
per figure family that applies to the run:

==================  ===========================================================  ==========
file                content                                                       applies
==================  ===========================================================  ==========
``snapshots.png``   robots on their paths at chosen instants: footprints,         always
                    headings, formation links (as Figs 5.10, 5.21, 6.2)
``tracking.png``    path and heading error of each robot over time                a ``ref``
``speeds.png``      virtual-vehicle speeds sdot (Sec. 4.2, (5.42))                an ``sdot``
``velocities.png``  applied velocities, and wheel rim speeds of omni robots,      always
                    against the model's limits ((3.2), (4.17)-(4.18))
``coordination.png`` coordination and formation errors from the truth             a team
                    (orchestrator/analysis/truth.py); the controllers' own figure
                    dashed as "reported"
``solve_times.png`` controller solve time per step                                an MPC
``faults.png``      messages dropped by the fault layer over time, partitions     faults
                    shaded
``tasks.png``       the task (formation) each robot works on, when it got there   a ``task``
``estimation.png``  each robot's pose estimate against the truth: position and    [sensing]
                    heading error with their 3-sigma bounds, NEES                 estimator
                    (orchestrator/analysis/estimation.py, docs/reference/sensing.md)
==================  ===========================================================  ==========

Errors follow the definitions of ``metrics.json`` (orchestrator/analysis/metrics.py): the path
error is the distance from the true position to the controller's reference point at the
same instant. Drops are reconstructed from the log: the fault layer
(``copath.wire.faults``) is seeded per directed link and consumes one draw set per message
in the sender's order, so replaying it over the recorded peer messages gives every
receiver's decision; the figure says whether the totals match the processes' closing
accounts. ``animate_run`` writes the snapshots as an animation (GIF, or MP4 where ffmpeg
exists). See docs/reference/viewing.md.
"""

from __future__ import annotations

import math
import pathlib
import shutil
import sys
from dataclasses import dataclass, field
from typing import Any, Callable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402

from copath.paths import wrap_to_pi  # noqa: E402
from copath.scenario import Scenario, parse_scenario  # noqa: E402
from copath.wire.keys import Keys  # noqa: E402
from copath.wire.messages import Command, PeerEnvelope, Truth  # noqa: E402

from orchestrator.log.mcap import read_log  # noqa: E402
from orchestrator.analysis.metrics import Trace, reported_coordination_series, trace_from_records  # noqa: E402
from orchestrator.view.foxglove import FaultReplay, communication_links, foxglove_layout  # noqa: E402
from orchestrator.analysis.estimation import estimate_series  # noqa: E402

__all__ = ["RunView", "load_run", "FAMILIES", "applicable", "plot_run", "animate_run"]

SNAPSHOTS = 5
"""Instants of the snapshot figure: evenly spaced from the first to the last tick (chosen)."""


@dataclass
class DropSeries:
    """Messages the fault layer dropped, reconstructed per receiver."""

    t: np.ndarray
    """Sender stamps of the dropped messages [s], sorted."""
    partitioned: np.ndarray
    """Whether each drop was a partition (else loss)."""
    accounted: int | None
    """dropped_by_faults + partitioned from the closing accounts, None without them."""


@dataclass
class RunView:
    """What the figures need, all from one run log."""

    scenario: Scenario
    keys: Keys
    trace: Trace
    truths: list[Truth]
    solve: dict[str, tuple[np.ndarray, np.ndarray]]
    peers: list[tuple[str, PeerEnvelope]] = field(repr=False)
    path: pathlib.Path | None = None

    @property
    def colors(self) -> dict[str, Any]:
        cmap = plt.get_cmap("tab10")
        return {n: cmap(i % 10) for i, n in enumerate(self.scenario.robot_names)}


def load_run(mcap_path: str | pathlib.Path) -> RunView:
    """Read a run log and the scenario recorded in it."""
    log = read_log(mcap_path)
    raw = log.scenario_raw
    if not raw:
        raise ValueError(f"{mcap_path}: no scenario in the log metadata (not a copath run log?)")
    scenario = parse_scenario(raw, source=str(raw.get("_source", "")))
    keys = Keys(log.run_id or "run")
    radii = {r.name: r.model.radius for r in scenario.robots}
    trace = trace_from_records(log.records, keys, radii)
    truths = sorted((r for _, _, r in log.records if isinstance(r, Truth)), key=lambda r: r.k)
    solve: dict[str, list] = {}
    peers = []
    for _, key, rec in log.records:
        if isinstance(rec, Command):
            solve.setdefault(keys.relative(key).split("/")[1], []).append((rec.t, rec.solve_ms))
        elif isinstance(rec, PeerEnvelope):
            peers.append((keys.relative(key), rec))
    solve_arr = {n: tuple(np.array(v).T) for n, v in solve.items() if v}
    return RunView(scenario, keys, trace, truths, solve_arr, peers, pathlib.Path(mcap_path))


# --------------------------------------------------------------------------- series
def _tracking(rt) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(t, path error, heading error or None) at the controller's steps with a reference."""
    rows = [(t, d["ref"]) for t, d in zip(rt.telemetry_t, rt.telemetry)
            if d.get("ref") is not None and not d.get("in_transition", False)]
    if not rows or not len(rt.t):
        return np.zeros(0), np.zeros(0), None
    t = np.array([r[0] for r in rows])
    width = min(len(r[1]) for r in rows)
    ref = np.array([r[1][:width] for r in rows], dtype=float)
    p = rt.pose_at(t)
    e = np.hypot(p[:, 0] - ref[:, 0], p[:, 1] - ref[:, 1])
    he = np.abs(wrap_to_pi(p[:, 2] - ref[:, 2])) if width >= 3 else None
    return t, e, he


def _telemetry_series(rt, name: str) -> tuple[np.ndarray, np.ndarray]:
    rows = [(t, d[name]) for t, d in zip(rt.telemetry_t, rt.telemetry) if isinstance(d.get(name), (int, float))]
    return (np.array([r[0] for r in rows]), np.array([r[1] for r in rows], dtype=float)) if rows else (np.zeros(0),) * 2


def _reported_coordination(view: RunView) -> tuple[np.ndarray, np.ndarray] | None:
    """The coordination the controllers report, over the same pairs as metrics.json."""
    return reported_coordination_series(view.trace, view.scenario)


def _truth_series(view: RunView):
    try:
        from orchestrator.analysis.truth import truth_series  # noqa: PLC0415
    except ImportError:  # older trees: telemetry only
        return None
    return truth_series(view.trace, view.scenario)  # None for a team without a geometry


def drops(view: RunView) -> DropSeries | None:
    """The fault layer's drop decisions, replayed over the recorded peer messages."""
    replay = FaultReplay(view.scenario)
    if not replay.active:
        return None
    t_drop, part = [], []
    for rel, env in sorted(view.peers, key=lambda p: (p[1].sender, p[1].seq)):  # each sender's order
        for _receiver, outcome in replay.decide(rel, env):
            if outcome is not None:
                t_drop.append(env.stamp)
                part.append(outcome == "partition")
    order = np.argsort(t_drop, kind="stable")
    stats = view.trace.stats
    accounted = None
    if any(n in stats for n in view.scenario.robot_names):
        accounted = int(sum(int(s.get("dropped_by_faults", 0)) + int(s.get("partitioned", 0))
                            for n, s in stats.items() if n != "sim"))
    return DropSeries(np.asarray(t_drop)[order], np.asarray(part, dtype=bool)[order], accounted)


# --------------------------------------------------------------------------- figures
def _draw_world(ax, view: RunView) -> None:
    for name, path in view.scenario.paths.items():
        s = np.linspace(0.0, path.length, max(100, int(path.length / 0.01)))
        p = path.pos(s)
        ax.plot(p[:, 0], p[:, 1], color="0.75", lw=1.0, zorder=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, lw=0.3)


def _draw_robots(ax, view: RunView, truth: Truth, alpha: float = 1.0, label: str | None = None,
                 links: bool = True) -> list:
    """Footprints, headings and formation links of the robots at one truth tick."""
    artists = []
    colors = view.colors
    pos = {n: p for n, p in zip(truth.names, truth.poses)}
    links = _links(view, truth.t, pos) if links else []
    if links:
        lc = LineCollection([[pos[a][:2], pos[b][:2]] for a, b in links], colors="0.35", linewidths=0.8,
                            linestyles="--", alpha=alpha, zorder=2)
        ax.add_collection(lc)
        artists.append(lc)
    for n, p in pos.items():
        r = view.trace.robots[n].radius if n in view.trace.robots else 0.1
        c = Circle((p[0], p[1]), r or 0.1, facecolor=colors.get(n, "C0"), edgecolor="k", lw=0.6, alpha=0.35 * alpha + 0.1,
                   zorder=3)
        ax.add_patch(c)
        a = ax.annotate("", xy=(p[0] + 1.6 * r * math.cos(p[2]), p[1] + 1.6 * r * math.sin(p[2])), xytext=(p[0], p[1]),
                        arrowprops=dict(arrowstyle="-|>", color=colors.get(n, "C0"), lw=1.2, alpha=alpha), zorder=4)
        artists += [c, a]
    for poly in truth.obstacles or []:
        pg = Polygon(np.asarray(poly), closed=True, facecolor="0.3", edgecolor="k", alpha=0.5 * alpha, zorder=2)
        ax.add_patch(pg)
        artists.append(pg)
    if label is not None and truth.poses:
        p = truth.poses[0]
        artists.append(ax.text(p[0], p[1], label, fontsize=7, ha="left", va="bottom", zorder=5))
    return artists


def _links(view: RunView, t: float, pos: dict) -> list[tuple[str, str]]:
    """Links up at ``t`` (a partition's cut links are not drawn), as in the Foxglove view."""
    return communication_links(view.scenario, t, pos)[0]


def _limits(ax, view: RunView) -> None:
    """Frame the paths and the trajectories (obstacles that drive away are left out)."""
    pts = [rt.pose[:, :2] for rt in view.trace.robots.values() if len(rt.pose)]
    pts += [path.pos(np.linspace(0.0, path.length, 200)) for path in view.scenario.paths.values()]
    if not pts:
        return
    allp = np.concatenate(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    r = max((rt.radius for rt in view.trace.robots.values()), default=0.1)
    pad = 0.05 * float(np.max(hi - lo)) + 2 * r
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)


def _targets(ax, view: RunView) -> None:
    """Each robot's last reported target position (Chapter 6), as a cross."""
    for n, rt in view.trace.robots.items():
        last = next((d["target"] for d in reversed(rt.telemetry) if d.get("target") is not None), None)
        if last is not None and len(last) >= 2:
            ax.plot(last[0], last[1], "x", color=view.colors.get(n), ms=6, mew=1.5, zorder=5)


def snapshot_times(view: RunView, count: int = SNAPSHOTS) -> list[int]:
    """Indices into ``view.truths`` of the snapshot instants."""
    n = len(view.truths)
    return sorted(set(np.linspace(0, n - 1, min(count, n)).round().astype(int).tolist())) if n else []


def fig_snapshots(view: RunView):
    fig, ax = plt.subplots(figsize=(7, 6))
    _draw_world(ax, view)
    for n, rt in view.trace.robots.items():
        ax.plot(rt.pose[:, 0], rt.pose[:, 1], color=view.colors.get(n), lw=0.8, alpha=0.6, label=n, zorder=2)
    idx = snapshot_times(view)
    sparse = len(view.scenario.edges()) <= 2 * len(view.scenario.robots) and view.scenario.network.range_m == 0
    for j, i in enumerate(idx):
        tr = view.truths[i]
        _draw_robots(ax, view, tr, alpha=0.4 + 0.6 * (j + 1) / len(idx), label=f"t={tr.t:.1f} s",
                     links=sparse or j == len(idx) - 1)  # dense graphs: links at the last instant only
    _targets(ax, view)
    _limits(ax, view)
    if len(view.trace.robots) <= 10:
        ax.legend(fontsize=7, loc="best")
    ax.set_title(f"{view.scenario.id}: snapshots at " + ", ".join(f"{view.truths[i].t:.1f}" for i in idx) + " s",
                 fontsize=9)
    return fig


def fig_tracking(view: RunView):
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    any_heading = False
    for n, rt in view.trace.robots.items():
        t, e, he = _tracking(rt)
        if len(t):
            a1.plot(t, e, color=view.colors.get(n), lw=1, label=n)
            if he is not None:
                any_heading = True
                a2.plot(t, he, color=view.colors.get(n), lw=1, label=n)
    a1.set_ylabel("path error [m]")
    a2.set_ylabel("heading error [rad]" if any_heading else "(no heading reference)")
    a2.set_xlabel("t [s]")
    for a in (a1, a2):
        a.grid(True, lw=0.3)
        _settle(a, view)
    a1.legend(fontsize=7, ncol=4)
    a1.set_title("distance of the true pose from each controller's reference", fontsize=9)
    return fig


def _settle(ax, view: RunView) -> None:
    """Shade the settling time (errors before it are not scored in metrics.json)."""
    end = view.trace.sim_time_s or (view.truths[-1].t if view.truths else 0.0)
    if view.scenario.run.settle_s > 0:
        ax.axvspan(0, min(view.scenario.run.settle_s, end), color="0.92", zorder=0)


def fig_speeds(view: RunView):
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for n, rt in view.trace.robots.items():
        t, v = _telemetry_series(rt, "sdot")
        if len(t):
            ax.plot(t, v, color=view.colors.get(n), lw=1, label=n)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("sdot [m/s]")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7, ncol=4)
    ax.set_title("virtual-vehicle speeds (controller telemetry)", fontsize=9)
    return fig


def fig_velocities(view: RunView):
    kinds = {r.model.kind for r in view.scenario.robots}
    rows = (2 if "unicycle" in kinds else 0) + (4 if "omni" in kinds else 0)
    fig, axes = plt.subplots(rows, 1, figsize=(8, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    axes = list(axes[:, 0])
    labels = []
    if "unicycle" in kinds:
        labels += [("unicycle", 0, "v [m/s]", "v_max"), ("unicycle", 1, "omega [rad/s]", "omega_max")]
    if "omni" in kinds:
        labels += [("omni", 0, "u [m/s]", None), ("omni", 1, "v [m/s]", None), ("omni", 2, "omega [rad/s]", None),
                   ("omni", "wheel", "max wheel rim speed [m/s]", "qdot_max")]
    for ax, (kind, comp, ylabel, limit) in zip(axes, labels):
        lims = set()
        for r in view.scenario.robots:
            rt = view.trace.robots.get(r.name)
            if r.model.kind != kind or rt is None or not len(rt.t):
                continue
            y = rt.wheel_max if comp == "wheel" else rt.command[:, comp] if rt.command.shape[1] > comp else None
            if y is None:
                continue
            ax.plot(rt.t, y, color=view.colors.get(r.name), lw=0.9, label=r.name)
            viol = rt.violated
            if viol.any():
                ax.plot(rt.t[viol], y[viol], "x", color="red", ms=3)
            if limit is not None:
                lims.add(float(getattr(r.model, limit)))
        for lim in lims:
            ax.axhline(lim, color="red", lw=0.8, ls="--")
            if comp != "wheel":
                ax.axhline(-lim, color="red", lw=0.8, ls="--")
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(True, lw=0.3)
    axes[0].legend(fontsize=7, ncol=6)
    axes[0].set_title("applied velocities (truth) against the model limits (dashed); x: request over the limit",
                      fontsize=9)
    axes[-1].set_xlabel("t [s]")
    return fig


def fig_coordination(view: RunView):
    ser = _truth_series(view)
    rep = _reported_coordination(view)
    has_form = ser is not None and bool(ser.formation_error)
    fig, axes = plt.subplots(2 if has_form else 1, 1, figsize=(8, 5.5 if has_form else 3.2), sharex=True,
                             squeeze=False)
    a1 = axes[0, 0]
    if ser is not None and ser.coordination_error is not None:
        a1.plot(ser.t, ser.coordination_error, color="k", lw=1.1, label="truth")
    if rep is not None:
        a1.plot(rep[0], rep[1], color="C1", lw=0.9, ls="--", label="reported")
    a1.set_ylabel("coordination error [m]")
    a1.legend(fontsize=7)
    a1.grid(True, lw=0.3)
    _settle(a1, view)
    a1.set_title("max over robot pairs of |xi_i - xi_j|", fontsize=9)
    if has_form:
        a2 = axes[1, 0]
        for n, e in ser.formation_error.items():
            a2.plot(ser.t, e, color=view.colors.get(n), lw=1, label=n)
        tr = np.asarray(ser.in_transition, dtype=bool)
        if tr.any():
            a2.fill_between(ser.t, 0, 1, where=tr, transform=a2.get_xaxis_transform(), color="C4", alpha=0.12,
                            label="formation change")
        a2.set_ylabel("formation error [m]")
        a2.legend(fontsize=7, ncol=4)
        a2.grid(True, lw=0.3)
        _settle(a2, view)
        a2.set_title("distance of each true position from its slot (truth)", fontsize=9)
    axes[-1, 0].set_xlabel("t [s]")
    return fig


def fig_solve_times(view: RunView):
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for n, (t, ms) in view.solve.items():
        ax.plot(t, ms, color=view.colors.get(n), lw=0.8, label=f"{n} (p50 {np.median(ms):.1f} ms)")
    ax.axhline(1000 * view.scenario.run.dt, color="red", lw=0.8, ls="--", label="control period")
    ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("solve time [ms]")
    ax.grid(True, lw=0.3, which="both")
    ax.legend(fontsize=7, ncol=3)
    ax.set_title("controller solve time per step", fontsize=9)
    return fig


def faults_caption(replayed: int, accounted: int | None) -> str:
    """What the two drop counts of the faults figure are. ``replayed``: the run's fault model
    applied again to every robot-to-robot message in the log (the bars); ``accounted``: what
    the receivers counted themselves (their closing accounts). The receivers decide a message
    when it arrives, so one still in flight when the run ended, or refused before the fault
    layer (docs/reference/faults.md), is in the first figure only."""
    if accounted is None:
        return f"{replayed} (the run's fault model replayed on the logged messages; no closing accounts)"
    if accounted == replayed:
        return f"{replayed} (replayed from the log = the receivers' own count)"
    return (f"{replayed} replayed from the log, {accounted} counted by the receivers "
            f"(the {abs(replayed - accounted)} more were in flight at the end or refused first)"
            if replayed > accounted else
            f"{replayed} replayed from the log, {accounted} counted by the receivers")


def fig_faults(view: RunView):
    ds = drops(view)
    fig, ax = plt.subplots(figsize=(8, 3.5))
    end = view.trace.sim_time_s or (view.truths[-1].t if view.truths else 1.0)
    for p in view.scenario.network.partitions:
        ax.axvspan(p.start_s, min(p.end_s, end), color="red", alpha=0.12,
                   label="partition " + ", ".join(f"{a}-{b}" for a, b in p.links))
    if ds is not None and len(ds.t):
        bins = np.arange(0.0, end + view.scenario.run.dt, max(view.scenario.run.dt, end / 100))
        ax.hist([ds.t[~ds.partitioned], ds.t[ds.partitioned]], bins=bins, stacked=True, color=["C0", "C3"],
                label=["lost (loss, burst)", "cut by a partition"])
    total = 0 if ds is None else len(ds.t)
    net = view.scenario.network
    ax.set_title(f"messages dropped by faults: {faults_caption(total, None if ds is None else ds.accounted)}\n"
                 f"loss {net.loss:g}, burst p_gb {net.burst_p_gb:g}, delay {net.delay_ms:g} ms", fontsize=8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("dropped per bin")
    ax.set_xlim(0, end)
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=7)
    return fig


def fig_estimation(view: RunView):
    """Estimate against truth: |p_hat - p| and |theta_hat - theta| with the filter's own
    3-sigma bounds, and the NEES against the 95 % band of chi2(3)."""
    from scipy.stats import chi2  # noqa: PLC0415

    fig, (a1, a2, a3) = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for n, rt in view.trace.robots.items():
        s = estimate_series(view.trace.estimates.get(n), rt.pose_at)
        if s is None:
            continue
        c = view.colors.get(n)
        err, cov = s["err"], s["cov"]
        a1.plot(s["t"], np.hypot(err[:, 0], err[:, 1]), color=c, lw=0.8, label=n)
        a1.plot(s["t"], 3 * np.sqrt(cov[:, 0, 0] + cov[:, 1, 1]), color=c, lw=0.6, ls="--")
        a2.plot(s["t"], np.abs(err[:, 2]), color=c, lw=0.8)
        a2.plot(s["t"], 3 * np.sqrt(cov[:, 2, 2]), color=c, lw=0.6, ls="--")
        nees = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[:, :, None])[:, :, 0])
        a3.semilogy(s["t"], np.maximum(nees, 1e-3), color=c, lw=0.6)
    lo, hi = chi2.ppf([0.025, 0.975], 3)
    a3.axhspan(lo, hi, color="0.9", zorder=0)
    a1.set_ylabel("position error [m]")
    a2.set_ylabel("heading error [rad]")
    a3.set_ylabel("NEES")
    a3.set_xlabel("t [s]")
    for a in (a1, a2, a3):
        a.grid(True, lw=0.3)
    a1.legend(fontsize=7, ncol=4)
    a1.set_title("estimate against truth; dashed: the filter's 3-sigma; grey: 95 % band of chi2(3)", fontsize=9)
    return fig


def fig_tasks(view: RunView):
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for n, rt in view.trace.robots.items():
        t, task = _telemetry_series(rt, "task")
        if len(t):
            ax.step(t, task, where="post", color=view.colors.get(n), lw=1, label=n)
            done = [tt for tt, d in zip(rt.telemetry_t, rt.telemetry) if d.get("task_done")]
            if done:
                ax.plot(done[0], task[np.searchsorted(t, done[0], side="right") - 1], "o", color=view.colors.get(n),
                        ms=4)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("task index")
    ax.grid(True, lw=0.3)
    if len(view.trace.robots) <= 16:
        ax.legend(fontsize=6, ncol=8)
    ax.set_title("task (formation) each robot works on (controller telemetry); dot: its target reached", fontsize=9)
    return fig


def _has_telemetry(view: RunView, name: str) -> bool:
    return any(isinstance(d.get(name), (int, float, list)) for rt in view.trace.robots.values() for d in rt.telemetry)


def _has_team(view: RunView) -> bool:
    return len(view.trace.robots) > 1 and (_has_telemetry(view, "xi") or _truth_series(view) is not None)


FAMILIES: dict[str, tuple[Callable[[RunView], bool], Callable[[RunView], Any]]] = {
    "snapshots": (lambda v: bool(v.truths), fig_snapshots),
    "tracking": (lambda v: _has_telemetry(v, "ref"), fig_tracking),
    "speeds": (lambda v: _has_telemetry(v, "sdot"), fig_speeds),
    "velocities": (lambda v: bool(v.truths), fig_velocities),
    "coordination": (_has_team, fig_coordination),
    "solve_times": (lambda v: any(np.any(ms > 0) for _, ms in v.solve.values()), fig_solve_times),
    "faults": (lambda v: drops(v) is not None, fig_faults),
    "tasks": (lambda v: _has_telemetry(v, "task"), fig_tasks),
    "estimation": (lambda v: any(v.trace.estimates.values()), fig_estimation),
}
"""Figure family -> (applies to this run?, draw)."""


def applicable(view: RunView) -> list[str]:
    """The figure families that apply to a run."""
    return [name for name, (ok, _) in FAMILIES.items() if ok(view)]


def plot_run(mcap_path: str | pathlib.Path, out_dir: str | pathlib.Path | None = None, *, animate: bool = False,
             progress: bool = False, dpi: int = 110) -> list[pathlib.Path]:
    """Write every applicable figure of a run, a Foxglove layout for its views
    (``foxglove-layout.json``) and, asked, its animation as files in ``out_dir`` (default:
    the log's directory); returns their paths."""
    view = load_run(mcap_path)
    out = pathlib.Path(out_dir) if out_dir is not None else pathlib.Path(mcap_path).parent
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in applicable(view):
        fig = FAMILIES[name][1](view)
        fig.tight_layout()
        f = out / f"{name}.png"
        fig.savefig(f, dpi=dpi)
        plt.close(fig)
        written.append(f)
    layout = out / "foxglove-layout.json"  # Foxglove: Layouts -> Import from file
    layout.write_text(foxglove_layout(view.scenario))
    written.append(layout)
    if animate:
        written.append(animate_run(view, out, progress=progress))
    return written


def animation_bar(stream) -> Callable[[int, int], None]:
    """The progress of an animation being written: on a terminal one line redrawn in place
    (``\\r``); otherwise (a log file, CI) a plain line at the first frame and at every tenth."""
    tty = bool(getattr(stream, "isatty", lambda: False)())

    def bar(i: int, total: int) -> None:
        done = int(30 * (i + 1) / total)
        text = f"  animation [{'#' * done}{'-' * (30 - done)}] {i + 1}/{total} frames"
        if tty:
            stream.write("\r" + text + ("\n" if i + 1 == total else ""))
        elif i == 0 or (10 * (i + 1)) // total > (10 * i) // total:
            stream.write(text + "\n")
        stream.flush()

    return bar


def animate_run(view: RunView, out_dir: pathlib.Path, *, frames: int = 200, fps: int = 15,
                progress: bool = True) -> pathlib.Path:
    """The run as an animation: MP4 where ffmpeg exists, else GIF (Pillow)."""
    from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter  # noqa: PLC0415

    n = len(view.truths)
    if n == 0:
        raise ValueError(f"{view.path}: no sim/truth records to animate")
    idx = np.unique(np.linspace(0, n - 1, min(frames, n)).round().astype(int))
    fig, ax = plt.subplots(figsize=(6, 5.5))
    _draw_world(ax, view)
    lo = np.min([rt.pose[:, :2].min(axis=0) for rt in view.trace.robots.values()], axis=0)
    hi = np.max([rt.pose[:, :2].max(axis=0) for rt in view.trace.robots.values()], axis=0)
    pad = 0.1 * float(np.max(hi - lo)) + 0.3
    for name, path in view.scenario.paths.items():
        p = path.pos(np.linspace(0.0, path.length, 200))
        lo, hi = np.minimum(lo, p.min(axis=0)), np.maximum(hi, p.max(axis=0))
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    trails = {nm: ax.plot([], [], color=view.colors.get(nm), lw=0.8)[0] for nm in view.trace.robots}
    drawn: list = []
    title = ax.set_title("", fontsize=9)

    def update(j: int):
        for a in drawn:
            a.remove()
        drawn.clear()
        tr = view.truths[idx[j]]
        for nm, line in trails.items():
            rt = view.trace.robots[nm]
            k = min(idx[j] + 1, len(rt.pose))
            line.set_data(rt.pose[:k, 0], rt.pose[:k, 1])
        drawn.extend(_draw_robots(ax, view, tr))
        title.set_text(f"{view.scenario.id}  t = {tr.t:.1f} s")
        return []

    anim = FuncAnimation(fig, update, frames=len(idx), blit=False)
    if shutil.which("ffmpeg"):
        f, writer = out_dir / "animation.mp4", FFMpegWriter(fps=fps)
    else:
        f, writer = out_dir / "animation.gif", PillowWriter(fps=fps)

    anim.save(str(f), writer=writer, dpi=90, progress_callback=animation_bar(sys.stderr) if progress else None)
    plt.close(fig)
    return f
