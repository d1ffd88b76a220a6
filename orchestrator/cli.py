"""``copath``: the command line of the fleet runtime.

Subcommands (``copath --version``; ``--log-level LEVEL`` before or after the subcommand)::

    copath run CONFIG [--out DIR] [--set KEY=VALUE]... [--duration S] [--clock lockstep|realtime]
                      [--seed N] [--delay MS] [--jitter MS] [--loss P] [--run-id ID] [--inprocess]
                      [--connect ENDPOINT] [--listen ENDPOINT] [--check] [--no-plots] [--live [PORT]]
    copath sweep CONFIG [--seeds 1-10] [--set KEY=V1,V2,...]... [--inprocess] [--jobs N] [--out DIR]
    copath envelope CONFIG [--delays MS,...] [--losses P,...] [--cells MS/P,...] [--seeds 1-3] [--inprocess]
    copath agent --run-id ID --robot NAME --config FILE [--connect ENDPOINT]
    copath sim   --run-id ID --config FILE [--connect ENDPOINT]
    copath info RUN.mcap [--json]
    copath metrics RUN.mcap [--out metrics.json]
    copath replay RUN.mcap [--speed X] [--run-id ID] [--connect ENDPOINT] [--live [PORT]]
    copath plot RUN.mcap [--out DIR] [--animate]
    copath scenarios [--json]
    copath validate CONFIG... [--set KEY=VALUE]...
    copath controllers [NAME...]
    copath bench solve|dmpc|fleet|scale|latency|secure|peers|floor|chaos|compare-metrics ... [--json]

CONFIG is a scenario file, or a bundled scenario by its file stem or its experiment id
(``copath run e5.5``). Exit codes: 0 done, 1 the run failed, 2 bad input, 3 a target of
the scenario's ``[targets]`` was missed (``--check``). A reader that goes away
(``copath info RUN.mcap | head``) ends the output quietly, with exit code 1.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import pathlib
import sys
from typing import Sequence

from copath.scenario import ConfigError, Scenario

from orchestrator import api

__all__ = ["main", "build_parser", "summary_table", "targets_table", "failure_lines"]

logger = logging.getLogger("copath")

EXIT_FAILED, EXIT_INPUT, EXIT_TARGETS = 1, 2, 3

_SHORTHANDS = (("duration", "run.duration_s"), ("clock", "run.clock"), ("seed", "run.seed"),
               ("delay", "network.delay_ms"), ("jitter", "network.jitter_ms"), ("loss", "network.loss"),
               ("secure", "run.secure"), ("on_robot_failure", "run.on_robot_failure"))


def _overrides(args: argparse.Namespace) -> dict:
    """``--set KEY=VALUE`` items (TOML literals) plus the shorthand flags (``--loss`` is
    ``--set network.loss=...``); a later --set of the same key wins."""
    out = {key: getattr(args, flag) for flag, key in _SHORTHANDS if getattr(args, flag, None) is not None}
    for item in getattr(args, "set", None) or []:
        k, v = api.parse_set(item)
        out[k] = api.parse_value(v)
    return out


def _fmt(v, digits=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def summary_table(metrics: dict) -> str:
    cols = [("path_error_max_m", "path max m"), ("path_error_rms_m", "path rms m"),
            ("heading_error_max_rad", "head max rad"), ("speed_error_rms_mps", "speed rms"),
            ("solve_ms_p50", "solve p50 ms"), ("solve_ms_p99", "solve p99 ms"),
            ("limit_violations", "limit viol"), ("missed_ticks", "missed")]
    head = f"{'robot':<10}" + "".join(f"{c[1]:>13}" for c in cols)
    lines = [f"scenario {metrics['scenario']}  run {metrics['run_id']}  clock {metrics['clock']}  "
             f"sim {_fmt(metrics['sim_time_s'], 1)} s  wall {_fmt(metrics['wall_time_s'], 1)} s  "
             f"(errors after {metrics['settle_s']} s)", head, "-" * len(head)]
    for name, m in metrics["robots"].items():
        lines.append(f"{name:<10}" + "".join(f"{_fmt(m.get(k)):>13}" for k, _ in cols))
    fleet = {k: v for k, v in metrics["fleet"].items() if v is not None}
    lines.append("fleet: " + "  ".join(f"{k}={_fmt(v)}" for k, v in fleet.items()))
    lines += failure_lines(metrics)
    return "\n".join(lines)


def failure_lines(metrics: dict) -> list[str]:
    """The summary's loud part: each robot whose controller failed (docs/reference/controllers.md,
    "When step() fails"); empty when none did."""
    from copath.grading import failed_robots

    failed = failed_robots(metrics)
    if not failed:
        return []
    lines = [f"CONTROLLER FAILED: robot {name}: {n} step{'s' if n != 1 else ''} raised or returned an "
             "invalid command (the robot stood still at each); every target misses" for name, n in failed.items()]
    return lines


def targets_table(results) -> str:
    """The scenario's targets against the run: one line each, PASS or MISS."""
    if not results:
        return "targets: none in this scenario ([targets] table)"
    lines = [f"targets ({sum(r.passed for r in results)}/{len(results)} met):"]
    for r in results:
        t = r.target
        who = f" ({r.worst})" if r.worst else ""
        val = "not measured" if r.value is None else f"{r.value:.4g}"
        why = f"  ({r.reason})" if getattr(r, "reason", None) else ""
        lines.append(f"  {'PASS' if r.passed else 'MISS'}  {t.key:<28} {val:>12}{who:<6} {t.sense} {t.threshold:g}{why}")
    return "\n".join(lines)


def _print_errors(cmd: str, config: str, exc: Exception) -> None:
    """Every problem of a scenario on its own line: ``cmd: FILE: key = value is not allowed; rule``."""
    errors = getattr(exc, "errors", None) or [str(exc)]
    for e in errors:
        print(f"{cmd}: {config}: {e}", file=sys.stderr)
    if len(errors) > 1:
        print(f"{cmd}: {len(errors)} problems; nothing was started", file=sys.stderr)


def _cmd_validate(args: argparse.Namespace) -> int:
    """``copath validate CONFIG... [--set KEY=VALUE]...``: exit 0 when every file is valid, 2 otherwise."""
    bad = 0
    try:
        overrides = _overrides(args)
    except (ConfigError, ValueError) as exc:
        _print_errors("copath validate", "--set", exc)
        return EXIT_INPUT
    for config in args.configs:
        try:  # --set: changed exactly as copath run --set changes it, then validated alike
            s = api.load(config, overrides)  # a path, a bundled stem or an experiment id, as copath run takes
        except (ConfigError, ValueError) as exc:
            _print_errors("copath validate", config, exc)
            bad += 1
        else:
            print(f"{config}: ok ({s.id}, {len(s.robots)} robots, "
                  f"controllers: {', '.join(sorted({r.controller for r in s.robots}))})")
    return 2 if bad else 0


def _cmd_controllers(args: argparse.Namespace) -> int:
    """``copath controllers [NAME...]``: every controller type a scenario may name, with each
    parameter's type, default and meaning (from its parameter dataclass; docs/reference/controller-parameters.md)."""
    import textwrap

    from agent.controllers import registered_names, resolve_controller

    from orchestrator.reference import fields_of

    names = registered_names()
    unknown = [n for n in args.names if n not in names]
    if unknown:
        print(f"copath controllers: {', '.join(unknown)} is not a registered controller; registered: "
              f"{', '.join(names)}", file=sys.stderr)
        return EXIT_INPUT
    for name in args.names or names:
        try:
            f = resolve_controller(name)
        except ConfigError as exc:
            print(f"{name:<22} (cannot load: {exc})")
            continue
        needs = [f"models: {', '.join(f.models)}" if f.models else "any model"]
        if f.needs_path:
            needs.append("needs a path")
        params = "" if f.config is None else f"  ({f.config.__module__}.{f.config.__qualname__})"
        print(f"{name:<22} {'; '.join(needs)}{params}")
        if f.config is None:
            print("    parameters: not declared (passed through unchecked)")
            continue
        for fi in fields_of(f.config):
            head = f"{fi.name} ({fi.type}, default {fi.default})"
            print(textwrap.fill(f"{head}: {fi.doc}" if fi.doc else head, width=100, initial_indent="    ",
                                subsequent_indent="        "))
    print("or an import path 'package.module:builder' (see docs/reference/controllers.md; every parameter: "
          "docs/reference/controller-parameters.md)")
    return 0


def _plots(mcap: pathlib.Path, out: pathlib.Path) -> None:
    """The run's figures (``copath plot``), when the plotting module is installed."""
    try:
        from orchestrator.view.plot import plot_run
    except ImportError:
        logger.debug("orchestrator.view.plot is not available; no figures")
        return
    try:
        files = plot_run(mcap, out)
        n = len(files) if files is not None and hasattr(files, "__len__") else None
        print(f"plots: {out}" + (f" ({n} figures)" if n is not None else ""))
    except Exception as exc:  # a figure must never fail a run that completed
        logger.warning("plots failed: %s", exc, exc_info=logger.isEnabledFor(logging.DEBUG))


def _finish(args: argparse.Namespace, scenario: Scenario, metrics: dict | None) -> int:
    """Summary table and targets; the exit code of --check."""
    from copath.grading import failed_robots, grade

    if metrics is None:
        return 0
    print(summary_table(metrics))
    results = grade(scenario.targets, metrics)
    print(targets_table(results))
    failed = failed_robots(metrics)
    if getattr(args, "check", False) and (failed or not all(r.passed for r in results)):
        missed = [r.target.key for r in results if not r.passed]
        why = [f"{len(missed)} target(s) missed: {', '.join(missed)}"] if missed else []
        why += [f"the controller of {', '.join(failed)} failed"] if failed else []
        print(f"copath run: --check: {'; '.join(why)}", file=sys.stderr)
        return EXIT_TARGETS
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from copath.wire.keys import valid_run_id

    from orchestrator.run.fleet import RunOptions, new_run_id, run_fleet
    from orchestrator.run.progress import Progress

    try:
        scenario = api.load(args.config, _overrides(args))  # file, bundled stem or experiment id
        run_id = args.run_id or new_run_id(scenario.id)
        valid_run_id(run_id)
        if args.inprocess and scenario.run.clock != "lockstep":
            raise ConfigError(f"run.clock = {scenario.run.clock!r} is not allowed with --inprocess; "
                              "in-process runs are lockstep only")
        for name in args.external:
            if name not in scenario.robot_names:
                raise ConfigError(f"--external = {name!r} is not allowed; the scenario's robots are "
                                  f"{', '.join(scenario.robot_names)}")
        if args.inprocess and args.external:
            raise ConfigError("--external is not allowed with --inprocess; external robots join a fleet run")
        if args.ros2:  # a live ROS 2 view: ROS 2 installed, a fleet run, robots not already on ROS 2
            from copath.ros2 import missing

            if (m := missing("--ros2")) is not None:
                raise ConfigError(m)
            if args.inprocess:
                raise ConfigError("--ros2 is not allowed with --inprocess; the ROS 2 view mirrors fleet runs")
            if scenario.world.ros2:
                raise ConfigError("--ros2 is not allowed with world.backend = 'ros2'; the robots publish their "
                                  "own /<robot>/odom (export the run with copath export --ros2)")
        if args.inprocess and args.live is not None:
            raise ConfigError(f"--live = {args.live} is not allowed with --inprocess; live views are served "
                              "by fleet runs and by copath replay --live")
    except (ConfigError, ValueError) as exc:
        _print_errors("copath run", args.config, exc)
        return EXIT_INPUT
    out = pathlib.Path(args.out or pathlib.Path("runs") / run_id)
    where = "in this process" if args.inprocess else f"{len(scenario.robots) + 1} processes"
    print(f"copath run {scenario.id} ({len(scenario.robots)} robots, {scenario.run.clock}, {where}) -> {out}",
          file=sys.stderr)
    if args.inprocess:
        progress = Progress(scenario.run.duration_s, enabled=not args.quiet,
                            starting="building controllers (solvers compile)").start()
        try:
            run = api.run(scenario, inprocess=True, out_dir=out, run_id=run_id, on_tick=progress.update)
        except KeyboardInterrupt:
            print("copath run: interrupted (Ctrl-C)", file=sys.stderr)
            return 130
        finally:
            progress.done()
        rc = _finish(args, scenario, run.metrics)
        print(f"log: {out / 'run.mcap'} (in-process run)\nmetrics: {out / 'metrics.json'}")
        if not args.no_plots:
            _plots(out / "run.mcap", out)
        return rc
    try:
        outcome = run_fleet(scenario, RunOptions(out_dir=out, run_id=run_id, progress=not args.quiet,
                                                 wall_timeout_s=args.wall_timeout, connect=tuple(args.connect),
                                                 listen=tuple(args.listen), live_port=args.live,
                                                 external=tuple(args.external), ros2_view=args.ros2,
                                                 start_timeout_s=600.0 if args.external else 120.0))
    except ValueError as exc:  # LivePortError: nothing was started
        if type(exc).__name__ != "LivePortError":
            raise
        print(f"copath run: {exc}", file=sys.stderr)
        return EXIT_INPUT
    rc = _finish(args, scenario, outcome.metrics)
    print(f"log: {out / 'run.mcap'}\nmetrics: {out / 'metrics.json'}")
    if not args.no_plots and (out / "run.mcap").is_file():
        _plots(out / "run.mcap", out)
    if not outcome.ok:
        print(f"copath run: FAILED: {outcome.reason}", file=sys.stderr)
        return EXIT_FAILED
    return rc


def _cmd_sweep(args: argparse.Namespace) -> int:
    import time

    from orchestrator.studies import sweep

    try:
        axes = sweep.parse_axes(args.set)
        seeds = sweep.parse_seeds(args.seeds) if args.seeds else None
        path = api.find_scenario(args.config)
        base = api.load(path)
        settings = sweep.plan(axes, seeds)
        scenarios = [api.load(path, st) for st in settings]  # every setting is checked before any run
        if args.inprocess and any(sc.run.clock != "lockstep" for sc in scenarios):
            raise ConfigError("run.clock = 'realtime' is not allowed with --inprocess; in-process runs are lockstep only")
        if args.jobs is not None and args.jobs < 1:
            raise ConfigError(f"--jobs = {args.jobs} is not allowed; must be >= 1")
    except (ConfigError, ValueError) as exc:
        _print_errors("copath sweep", args.config, exc)
        return EXIT_INPUT
    out = pathlib.Path(args.out or pathlib.Path("runs") / f"sweep-{base.id}-{time.strftime('%Y%m%d-%H%M%S')}")
    jobs = args.jobs or sweep.default_jobs(len(base.robots), args.inprocess)
    kind = "in-process runs" if args.inprocess else "fleet runs"
    print(f"copath sweep {base.id}: {len(settings)} {kind}, {jobs} at a time -> {out}", file=sys.stderr)
    t0 = time.monotonic()

    def done(row, n):
        if args.quiet:
            return
        wall = time.monotonic() - t0
        eta = wall / n * (len(settings) - n)
        what = ", ".join(f"{k}={v}" for k, v in row.setting.items())
        status = "ok" if row.ok else f"FAILED ({row.failure})"
        print(f"  [{n}/{len(settings)}] {what}: {status}, {row.wall_s:.1f} s  (ETA {eta:.0f} s)", file=sys.stderr)

    try:
        rows = sweep.run_sweep(path, axes, seeds, out_dir=out, inprocess=args.inprocess, jobs=jobs,
                               wall_timeout_s=args.wall_timeout, on_done=done)
    except KeyboardInterrupt:
        print(f"copath sweep: interrupted; the finished runs are in {out / 'sweep.csv'}", file=sys.stderr)
        return 130
    text = sweep.format_summary(rows)
    (out / "summary.txt").write_text(text + "\n")
    print(text)
    files = [] if args.no_plots else sweep.plot_sweep(rows, out, {t.key: t.threshold for t in base.targets})
    print(f"table: {out / 'sweep.csv'}" + (f"\nplots: {len(files)} in {out}" if files else ""))
    failed = sum(not r.ok for r in rows)
    if failed:
        print(f"copath sweep: {failed} of {len(rows)} runs failed", file=sys.stderr)
        return EXIT_FAILED
    if args.check and any(r.targets_met < r.targets_total for r in rows):
        print("copath sweep: --check: targets missed in some runs", file=sys.stderr)
        return EXIT_TARGETS
    return 0


def _cmd_envelope(args: argparse.Namespace) -> int:
    import time

    from orchestrator.studies import envelope, sweep

    try:
        path = api.find_scenario(args.config)
        base = api.load(path, list(args.set))
        cells = envelope.parse_cells(args.cells) if args.cells else envelope.grid(
            envelope.parse_numbers(args.delays, "--delays"), envelope.parse_numbers(args.losses, "--losses"))
        seeds = sweep.parse_seeds(args.seeds)
        metric = args.metric or envelope.headline_metric(base)
        if metric not in api.HEADLINE:
            raise ConfigError(f"--metric = {metric!r} is not allowed; one of {', '.join(api.HEADLINE)}")
        if args.inprocess and base.run.clock != "lockstep":
            raise ConfigError("run.clock = 'realtime' is not allowed with --inprocess; in-process runs are lockstep only")
        if args.jobs is not None and args.jobs < 1:
            raise ConfigError(f"--jobs = {args.jobs} is not allowed; must be >= 1")
    except (ConfigError, ValueError) as exc:
        _print_errors("copath envelope", args.config, exc)
        return EXIT_INPUT
    out = pathlib.Path(args.out or pathlib.Path("runs") / f"envelope-{base.id}-{time.strftime('%Y%m%d-%H%M%S')}")
    n = len(cells) * len(seeds)
    print(f"copath envelope {base.id}: {len(cells)} cells x {len(seeds)} seeds = {n} runs -> {out}", file=sys.stderr)

    def done(row, k):
        if not args.quiet:
            what = ", ".join(f"{key}={v}" for key, v in row.setting.items())
            print(f"  [{k}/{n}] {what}: {'ok' if row.ok else f'FAILED ({row.failure})'}, {row.wall_s:.1f} s",
                  file=sys.stderr)

    try:
        rows = envelope.run_envelope(path, cells, seeds, out_dir=out, fixed=args.set, inprocess=args.inprocess,
                                     jobs=args.jobs, wall_timeout_s=args.wall_timeout, on_done=done)
    except ConfigError as exc:
        _print_errors("copath envelope", args.config, exc)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print(f"copath envelope: interrupted; the finished runs are under {out}", file=sys.stderr)
        return 130
    target = next((t.threshold for t in base.targets if t.key == metric), None)
    result = envelope.cells_of(rows, metric, target)
    envelope.write_envelope_csv(result, metric, out / "envelope.csv")
    text = envelope.format_envelope(result, metric)
    (out / "summary.txt").write_text(text + "\n")
    print(text)
    print(f"table: {out / 'envelope.csv'}")
    if not args.no_plots:
        print(f"plot: {envelope.plot_envelope(result, metric, out / f'envelope-{metric}.png', base.id)}")
    failed = sum(not r.ok for r in rows)
    if failed:
        print(f"copath envelope: {failed} of {len(rows)} runs failed", file=sys.stderr)
        return EXIT_FAILED
    return 0


def _run_facts(log: pathlib.Path, info: dict) -> dict:
    """Sim time, seed, fault settings and headline figures of a logged run (metrics.json
    next to the log, else computed from the log's truth)."""
    scen = info.get("scenario") or {}
    net = dict(scen.get("network") or {})
    faults = {k: v for k, v in net.items() if v not in (0, 0.0, [], None) and k != "burst_p_bg"}
    noise = {f"noise.{k}": v for k, v in (scen.get("noise") or {}).items() if v not in (0, 0.0, None, [0, 0, 0])}
    try:
        run = api.open_run(log)
        metrics = run.metrics
    except Exception as exc:  # a log without truth still has an info page
        logger.debug("no metrics for %s: %s", log, exc)
        metrics = {}
    return {
        "sim_time_s": metrics.get("sim_time_s"),
        "wall_time_s": metrics.get("wall_time_s"),
        "seed": (scen.get("run") or {}).get("seed", 0),
        "faults": {**{f"network.{k}": v for k, v in faults.items()}, **noise},
        "headline": api.headline(metrics) if metrics else {},
    }


def _cmd_info(args: argparse.Namespace) -> int:
    from orchestrator.log.replay import format_info, log_info, print_json

    try:
        info = log_info(args.log)
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath info: {exc}", file=sys.stderr)
        return EXIT_INPUT
    facts = _run_facts(pathlib.Path(args.log), info)
    if args.json:
        print_json({**{k: v for k, v in info.items() if k != "scenario" or args.scenario}, **facts})
    else:
        print(format_info(info))
        print(f"Sim time:     {_fmt(facts['sim_time_s'], 2)} s")
        if facts["wall_time_s"] is not None:  # a longer span than Duration: say why
            print(f"Run time:     {_fmt(facts['wall_time_s'], 1)} s (wall clock, metrics.json wall_time_s: the "
                  "whole run, process start-up, solver compilation and shut-down included)")
        print(f"Seed:         {facts['seed']}")
        faults = facts["faults"]
        print("Faults:       " + (", ".join(f"{k}={json.dumps(v)}" for k, v in faults.items()) or "none"))
        shown = {k: v for k, v in facts["headline"].items() if v is not None}
        if shown:
            print("Metrics:      " + "  ".join(f"{k}={int(v) if float(v).is_integer() else _fmt(v, 4)}"
                                               for k, v in shown.items()))
        if args.scenario:
            print(json.dumps(info["scenario"], indent=1))
    return 0


def _cmd_metrics(args: argparse.Namespace) -> int:
    """``copath metrics RUN.mcap [--out FILE]``: metrics.json recomputed from a run log."""
    from orchestrator.analysis.metrics import metrics_from_log

    try:
        m = metrics_from_log(args.log)
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath metrics: {exc}", file=sys.stderr)
        return EXIT_INPUT
    text = json.dumps(m, indent=2)
    if args.out:
        pathlib.Path(args.out).write_text(text)
        print(summary_table(m))
        print(f"metrics: {args.out}")
    else:
        print(text)
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    import threading

    from orchestrator.log.replay import replay

    live = feeder = None
    stop = threading.Event()
    try:
        if args.live is not None:  # the log's Foxglove views, served while it replays
            from orchestrator.view.live import LiveViz, serve_log
            from orchestrator.view.foxglove import TOPICS

            if not pathlib.Path(args.log).is_file():
                raise FileNotFoundError(f"run log {args.log!r} does not exist")
            live = LiveViz(args.live)
            live.advertise(TOPICS)
            print(f"live views: {live.url} (Foxglove: Open connection -> Foxglove WebSocket)", file=sys.stderr)
            feeder = threading.Thread(target=serve_log, args=(args.log, live), daemon=True,
                                      kwargs={"speed": args.speed, "stop": stop})
            feeder.start()
        res = replay(args.log, speed=args.speed, run_id=args.run_id, connect=tuple(args.connect),
                     listen=tuple(args.listen), wait_for=args.wait_for, pace=args.pace, record=args.record,
                     announce=lambda e: print(f"replaying {args.log} on {e}", file=sys.stderr, flush=True))
    except (FileNotFoundError, ValueError, TimeoutError) as exc:
        print(f"copath replay: {exc}", file=sys.stderr)
        return 2
    finally:
        if feeder is not None:
            feeder.join(timeout=5.0)
            stop.set()
        if live is not None:
            live.close()
    print(f"published {res.published} messages over {res.duration_s:.2f} s on {res.endpoint}")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from orchestrator.view.plot import plot_run

    try:
        files = plot_run(args.log, args.out, animate=args.animate, progress=True)
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath plot: {exc}", file=sys.stderr)
        return EXIT_INPUT
    for f in files:
        print(f)
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    """``copath export --ros2 RUN.mcap OUT.mcap``: the run as a ROS 2 bag (orchestrator/log/export.py)."""
    from orchestrator.log.export import export_ros2

    if not pathlib.Path(args.log).is_file():
        print(f"copath export: {args.log} = no such run log", file=sys.stderr)
        return EXIT_INPUT
    try:
        res = export_ros2(args.log, args.out)
    except RuntimeError as exc:  # the ros2 extra is missing: one line saying what to install
        print(f"copath export: {exc}", file=sys.stderr)
        return EXIT_INPUT
    print(f"{args.out}: {res['messages']} messages in {res['wall_s']:.2f} s ({res['rate_msg_per_s']} msg/s); "
          + ", ".join(f"{t} {n}" for t, n in res["topics"].items()))
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    """The bundled scenarios: file stem, experiment id, robots and title."""
    rows = []
    for b in api.bundled_scenarios():
        try:
            s = api.load(b.path)
            rows.append({"stem": b.stem, "experiment": b.experiment, "robots": len(s.robots), "title": s.title,
                         "targets": len(s.targets), "error": None})
        except (ConfigError, ValueError) as exc:
            rows.append({"stem": b.stem, "experiment": b.experiment, "robots": None, "title": b.title,
                         "targets": None, "error": str(exc)})
    if getattr(args, "json", False):
        print(json.dumps(rows, indent=1))
        return 0
    print(f"bundled scenarios in {api.bundled_dir()} (run one by stem or experiment id: copath run e5.5)")
    for r in rows:
        if r["error"]:
            print(f"{r['stem']:<42} {r['experiment'] or '-':<6} INVALID: {r['error']}")
        else:
            print(f"{r['stem']:<42} {r['experiment'] or '-':<6} {r['robots']:>3} robots  {r['title']}")
    return 0


def _cmd_bench(args: argparse.Namespace, rest: list[str]) -> int:
    from orchestrator.studies.bench.harness import main as bench_main

    return bench_main(args.what, rest)


LOG_LEVELS = ("debug", "info", "warning", "error")


def build_parser() -> argparse.ArgumentParser:
    from orchestrator.studies.bench.harness import SUBCOMMANDS  # the table only (standard library imports)
    from orchestrator.version import software_version

    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--log-level", choices=LOG_LEVELS, default=argparse.SUPPRESS,
                        help="logging level of this process [warning]")
    p = argparse.ArgumentParser(prog="copath", description="Coordinated path following and formation control "
                                "of robot fleets: one process per robot over Zenoh.", parents=[common])
    p.add_argument("--version", action="version", version=f"copath {software_version()}")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scenario as a fleet of processes and record it", parents=[common])
    r.add_argument("config", help="scenario file, bundled file stem or experiment id (e.g. e5.5; see copath scenarios)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any scenario value (TOML literal), e.g. network.delay_ms=100, "
                   "robots.r1.pose=[0,0,0]; repeatable")
    r.add_argument("--out", help="output directory [runs/<run id>]")
    r.add_argument("--duration", type=float, help="simulated duration [s]")
    r.add_argument("--clock", choices=("lockstep", "realtime"))
    r.add_argument("--seed", type=int)
    r.add_argument("--delay", type=float, metavar="MS", help="robot-to-robot delay [ms]")
    r.add_argument("--jitter", type=float, metavar="MS", help="extra uniform delay [ms]")
    r.add_argument("--loss", type=float, metavar="P", help="robot-to-robot loss probability")
    r.add_argument("--run-id", help="run id (letters, digits, '_-.') [scenario-time-random]")
    r.add_argument("--wall-timeout", type=float, metavar="S", help="give up after S wall seconds")
    r.add_argument("--inprocess", action="store_true",
                   help="run in this process (lockstep, no Zenoh); the log is written from memory")
    r.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint the run's router connects to (multi-host runs), e.g. tcp/10.0.0.2:7447")
    r.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint the run's router listens on [a free loopback port], e.g. tcp/0.0.0.0:7447")
    r.add_argument("--check", action="store_true", help=f"exit {EXIT_TARGETS} when a target of [targets] is missed")
    r.add_argument("--no-plots", action="store_true", help="do not write figures into the run directory")
    r.add_argument("--live", type=int, nargs="?", const=8765, metavar="PORT",
                   help="serve live Foxglove views on ws://localhost:PORT while the fleet runs [8765]")
    r.add_argument("--on-robot-failure", choices=("fail", "continue", "restart"),
                   help="when a robot process dies or freezes: end the run, go on without it, or restart it "
                        "(run.on_robot_failure; docs/reference/faults.md)")
    r.add_argument("--external", action="append", default=[], metavar="ROBOT",
                   help="do not start this robot: print its copath agent command and wait for it (repeatable)")
    r.add_argument("--secure", action=argparse.BooleanOptionalAction, default=None,
                   help="per-run credentials and access control on the run's router (run.secure, on by "
                        "default; --no-secure for robots behind a router of their own; docs/reference/security.md)")
    r.add_argument("--ros2", action="store_true",
                   help="mirror the run into ROS 2 live: /<robot>/odom, /<robot>/plan, /paths/* (docs/reference/ros2.md)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    sw = sub.add_parser("sweep", help="run the product of settings and seeds; one table and plots", parents=[common])
    sw.add_argument("config", help="scenario file, bundled file stem or experiment id")
    sw.add_argument("--seeds", metavar="SEEDS", help="seeds to run for every setting, e.g. 1-10 or 1,4,9")
    sw.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="a swept key and its values (TOML literals), e.g. network.loss=0,0.1,0.2; repeatable")
    sw.add_argument("--inprocess", action="store_true", help="in-process lockstep runs instead of fleets")
    sw.add_argument("-j", "--jobs", type=int, help="runs at once [cores / processes per run]")
    sw.add_argument("--out", help="output directory [runs/sweep-<scenario>-<time>]")
    sw.add_argument("--wall-timeout", type=float, metavar="S", help="give up a run after S wall seconds")
    sw.add_argument("--check", action="store_true", help=f"exit {EXIT_TARGETS} when any run misses a target")
    sw.add_argument("--no-plots", action="store_true", help="no figures")
    sw.add_argument("-q", "--quiet", action="store_true", help="no line per finished run")
    en = sub.add_parser("envelope", help="delay x loss grid with several seeds per cell; a table and a heat map "
                        "of the headline figure", parents=[common])
    en.add_argument("config", help="scenario file, bundled file stem or experiment id")
    en.add_argument("--delays", default="0,100,300,500,700,1000", metavar="MS,...",
                    help="robot-to-robot delays [ms] [0,100,300,500,700,1000]")
    en.add_argument("--losses", default="0,0.2,0.3,0.5", metavar="P,...", help="loss probabilities [0,0.2,0.3,0.5]")
    en.add_argument("--cells", metavar="MS/P,...", help="run these (delay, loss) cells instead of the grid, "
                    "e.g. 0/0,300/0.3,1000/0.5")
    en.add_argument("--seeds", default="1-3", metavar="SEEDS", help="seeds of every cell, e.g. 1-3 or 1,4 [1-3]")
    en.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a setting of every run, e.g. run.duration_s=120; repeatable")
    en.add_argument("--metric", help="headline figure [tasks_completed or coordination_error_max_m, "
                    "from the scenario's targets]")
    en.add_argument("--inprocess", action="store_true", help="in-process lockstep runs instead of fleets")
    en.add_argument("-j", "--jobs", type=int, help="runs at once [cores / processes per run]")
    en.add_argument("--out", help="output directory [runs/envelope-<scenario>-<time>]")
    en.add_argument("--wall-timeout", type=float, metavar="S", help="give up a run after S wall seconds")
    en.add_argument("--no-plots", action="store_true", help="no heat map")
    en.add_argument("-q", "--quiet", action="store_true", help="no line per finished run")
    sub.add_parser("agent", help="run one robot process (see copath agent --help)", add_help=False)
    sub.add_parser("sim", help="run the simulator process (see copath sim --help)", add_help=False)
    i = sub.add_parser("info", help="summarise a run log", parents=[common])
    i.add_argument("log")
    i.add_argument("--json", action="store_true")
    i.add_argument("--scenario", action="store_true", help="also print the recorded scenario")
    mt = sub.add_parser("metrics", help="recompute metrics.json from a run log (from the truth it recorded)")
    mt.add_argument("log")
    mt.add_argument("--out", help="write metrics.json here [print it]")
    rp = sub.add_parser("replay", help="republish a run log on Zenoh with its original timing", parents=[common])
    rp.add_argument("log")
    rp.add_argument("--speed", type=float, default=1.0)
    rp.add_argument("--run-id", help="publish under this run id instead of the recorded one")
    rp.add_argument("--wait-for", metavar="N|Ss", help="before the first message, wait for N sessions to join "
                    "(and a subscriber to match), or for S seconds (e.g. 2.5s)")
    rp.add_argument("--pace", choices=("wall", "sim"), default="wall",
                    help="space messages by recorded wall time (default) or by simulated time")
    rp.add_argument("--record", metavar="OUT.mcap", help="also write what is republished to this log")
    rp.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT")
    rp.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT")
    rp.add_argument("--live", type=int, nargs="?", const=8765, metavar="PORT",
                    help="serve the log's Foxglove views on ws://localhost:PORT while it replays [8765]")
    pl = sub.add_parser("plot", help="figures of a run from its log (PNG; --animate: GIF or MP4)", parents=[common])
    pl.add_argument("log")
    pl.add_argument("--out", help="output directory [the log's directory]")
    pl.add_argument("--animate", action="store_true", help="also write an animation of the run")
    ex = sub.add_parser("export", help="write a run log in another format (--ros2: a ROS 2 bag; docs/reference/ros2.md)",
                        parents=[common])
    ex.add_argument("--ros2", action="store_true", required=True,
                    help="a ROS 2 bag: MCAP, cdr encoding, ros2msg schemas (odom, tf, plans, reference paths)")
    ex.add_argument("log", metavar="RUN.mcap")
    ex.add_argument("out", metavar="OUT.mcap")
    sc = sub.add_parser("scenarios", help="list the bundled scenarios", parents=[common])
    sc.add_argument("--json", action="store_true")
    v = sub.add_parser("validate", help="check scenario files (controller parameters included) and print "
                       "every problem; starts nothing")
    v.add_argument("configs", nargs="+", metavar="CONFIG")
    v.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="change a value first, as copath run --set does (TOML literal); repeatable")
    ct = sub.add_parser("controllers", help="list the controller types (built-in and installed) and their parameters")
    ct.add_argument("names", nargs="*", metavar="NAME", help="only these controller types")
    b = sub.add_parser("bench", help="benchmarks that print figures", add_help=False)
    b.add_argument("what", choices=tuple(SUBCOMMANDS))
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """The ``copath`` command; a reader that goes away (``copath info RUN.mcap | head``)
    ends the output quietly, without a BrokenPipeError traceback."""
    try:
        rc = _main(argv)
        sys.stdout.flush()  # inside the try: a closed pipe fails here, not at interpreter exit
        return rc
    except BrokenPipeError:
        # the Python documentation's recipe (signal module, "Note on SIGPIPE"): point stdout
        # at devnull so the flush at exit does not fail again
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):  # stdout is not a file (a test's capture)
            pass
        return EXIT_FAILED


def _main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "agent":
        from agent.node import main as agent_main

        return agent_main(argv[1:])
    if argv and argv[0] == "sim":
        from agent.controllers import task_queues
        from sim.node import main as sim_main

        return sim_main(argv[1:], tasks_of=task_queues)  # the families' done rules, asked here
    parser = build_parser()
    bench = bool(argv) and argv[0] == "bench"
    args, rest = parser.parse_known_args(argv) if bench else (parser.parse_args(argv), [])
    level = getattr(args, "log_level", "warning").upper()
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)
    if bench:
        return _cmd_bench(args, rest)
    handlers = {"plot": _cmd_plot, "run": _cmd_run, "sweep": _cmd_sweep, "envelope": _cmd_envelope, "info": _cmd_info, "metrics": _cmd_metrics, "replay": _cmd_replay, "scenarios": _cmd_scenarios, "export": _cmd_export,
                "validate": _cmd_validate, "controllers": _cmd_controllers}
    return handlers[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
