"""``copath``: the command line of the fleet runtime.

Subcommands::

    copath run CONFIG [--out DIR] [--duration S] [--clock lockstep|realtime] [--seed N]
                      [--delay MS] [--jitter MS] [--loss P] [--run-id ID] [--inprocess]
    copath agent --run-id ID --robot NAME --config FILE [--connect ENDPOINT]
    copath sim   --run-id ID --config FILE [--connect ENDPOINT]
    copath info RUN.mcap [--json]
    copath metrics RUN.mcap [--out metrics.json]
    copath replay RUN.mcap [--speed X] [--run-id ID] [--connect ENDPOINT]
    copath scenarios
    copath bench solve|dmpc ...
"""

from __future__ import annotations

import argparse
import json
import logging
import pathlib
import sys
from typing import Sequence

from copath.scenario import ConfigError, Scenario, load_scenario

from .validate import validate_file, validate_scenario

__all__ = ["main"]

CONFIGS = pathlib.Path(__file__).resolve().parents[1] / "configs"


def _overrides(args: argparse.Namespace, scenario: Scenario) -> Scenario:
    run, net = {}, {}
    if args.duration is not None:
        run["duration_s"] = args.duration
    if args.clock is not None:
        run["clock"] = args.clock
    if args.seed is not None:
        run["seed"] = args.seed
    if args.delay is not None:
        net["delay_ms"] = args.delay
    if args.jitter is not None:
        net["jitter_ms"] = args.jitter
    if args.loss is not None:
        net["loss"] = args.loss
    sections = {k: v for k, v in (("run", run), ("network", net)) if v}
    return scenario.with_overrides(**sections) if sections else scenario


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
    return "\n".join(lines)


def _print_errors(cmd: str, config: str, exc: Exception) -> None:
    """Every problem of a scenario on its own line: ``cmd: FILE: key = value is not allowed; rule``."""
    errors = getattr(exc, "errors", None) or [str(exc)]
    for e in errors:
        print(f"{cmd}: {config}: {e}", file=sys.stderr)
    if len(errors) > 1:
        print(f"{cmd}: {len(errors)} problems; nothing was started", file=sys.stderr)


def _cmd_validate(args: argparse.Namespace) -> int:
    """``copath validate CONFIG...``: exit 0 when every file is valid, 2 otherwise."""
    bad = 0
    for config in args.configs:
        try:
            s = validate_file(config)
        except (ConfigError, ValueError) as exc:
            _print_errors("copath validate", config, exc)
            bad += 1
        else:
            print(f"{config}: ok ({s.id}, {len(s.robots)} robots, "
                  f"controllers: {', '.join(sorted({r.controller for r in s.robots}))})")
    return 2 if bad else 0


def _cmd_controllers(args: argparse.Namespace) -> int:
    """``copath controllers``: every controller type a scenario may name, with its parameters."""
    from agent.controllers import registered_names, resolve_controller

    for name in registered_names():
        try:
            f = resolve_controller(name)
        except ConfigError as exc:
            print(f"{name:<22} (cannot load: {exc})")
            continue
        needs = [f"models: {', '.join(f.models)}" if f.models else "any model"]
        if f.needs_path:
            needs.append("needs a path")
        params = "" if f.config is None else f"  config: {f.config.__module__}.{f.config.__qualname__}"
        print(f"{name:<22} {'; '.join(needs)}{params}")
    print("or an import path 'package.module:builder' (see docs/controllers.md)")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .fleet import RunOptions, new_run_id, run_fleet

    try:
        scenario = validate_scenario(_overrides(args, validate_file(args.config)))
        run_id = args.run_id or new_run_id(scenario.id)
        from copath.wire.keys import valid_run_id

        valid_run_id(run_id)
    except (ConfigError, ValueError) as exc:
        _print_errors("copath run", args.config, exc)
        return 2
    out = pathlib.Path(args.out or pathlib.Path("runs") / run_id)
    if args.inprocess:
        from .inprocess import run_scenario

        if scenario.run.clock != "lockstep":
            print("copath run: --inprocess runs lockstep only; drop --clock realtime", file=sys.stderr)
            return 2
        out.mkdir(parents=True, exist_ok=True)
        res = run_scenario(scenario, run_id=run_id)
        res.metrics["ok"], res.metrics["failure"] = True, None
        (out / "metrics.json").write_text(json.dumps(res.metrics, indent=2))
        print(summary_table(res.metrics))
        print(f"metrics: {out / 'metrics.json'} (in-process run: no MCAP log)")
        return 0
    print(f"copath run {scenario.id} ({len(scenario.robots)} robots, {scenario.run.clock}) -> {out}", file=sys.stderr)
    outcome = run_fleet(scenario, RunOptions(out_dir=out, run_id=run_id, progress=not args.quiet,
                                             wall_timeout_s=args.wall_timeout))
    if outcome.metrics is not None:
        print(summary_table(outcome.metrics))
    print(f"log: {out / 'run.mcap'}\nmetrics: {out / 'metrics.json'}")
    if not outcome.ok:
        print(f"copath run: FAILED: {outcome.reason}", file=sys.stderr)
        return 1
    return 0


def _cmd_info(args: argparse.Namespace) -> int:
    from .replay import format_info, log_info, print_json

    try:
        info = log_info(args.log)
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath info: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print_json({k: v for k, v in info.items() if k != "scenario" or args.scenario})
    else:
        print(format_info(info))
        if args.scenario:
            print(json.dumps(info["scenario"], indent=1))
    return 0


def _cmd_metrics(args: argparse.Namespace) -> int:
    """``copath metrics RUN.mcap [--out FILE]``: metrics.json recomputed from a run log."""
    from .metrics import metrics_from_log

    try:
        m = metrics_from_log(args.log)
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath metrics: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(m, indent=2)
    if args.out:
        pathlib.Path(args.out).write_text(text)
        print(summary_table(m))
        print(f"metrics: {args.out}")
    else:
        print(text)
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    from .replay import replay

    try:
        res = replay(args.log, speed=args.speed, run_id=args.run_id, connect=tuple(args.connect),
                     listen=tuple(args.listen),
                     announce=lambda e: print(f"replaying {args.log} on {e}", file=sys.stderr, flush=True))
    except (FileNotFoundError, ValueError) as exc:
        print(f"copath replay: {exc}", file=sys.stderr)
        return 2
    print(f"published {res.published} messages over {res.duration_s:.2f} s on {res.endpoint}")
    return 0


def _cmd_scenarios(args: argparse.Namespace) -> int:
    for f in sorted(CONFIGS.glob("e*.toml")):
        try:
            s = load_scenario(f)
            print(f"{f.name:<48} {len(s.robots):>3} robots  {s.title}")
        except ConfigError as exc:
            print(f"{f.name:<48} INVALID: {exc}")
    return 0


def _cmd_bench(args: argparse.Namespace, rest: list[str]) -> int:
    import importlib

    mod = importlib.import_module(f"orchestrator.bench_{args.what}")
    p = argparse.ArgumentParser(prog=f"copath bench {args.what}")
    mod.add_arguments(p)
    return int(mod.run(p.parse_args(rest)) or 0)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="copath", description="Coordinated path following and formation control "
                                "of robot fleets: one process per robot over Zenoh.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run a scenario as a fleet of processes and record it")
    r.add_argument("config", help="scenario file, e.g. configs/e5.5-column-lemniscate.toml")
    r.add_argument("--out", help="output directory [runs/<run id>]")
    r.add_argument("--duration", type=float, help="simulated duration [s]")
    r.add_argument("--clock", choices=("lockstep", "realtime"))
    r.add_argument("--seed", type=int)
    r.add_argument("--delay", type=float, metavar="MS", help="robot-to-robot delay [ms]")
    r.add_argument("--jitter", type=float, metavar="MS", help="extra uniform delay [ms]")
    r.add_argument("--loss", type=float, metavar="P", help="robot-to-robot loss probability")
    r.add_argument("--run-id", help="run id (letters, digits, '_-.') [scenario-time-random]")
    r.add_argument("--wall-timeout", type=float, metavar="S", help="give up after S wall seconds")
    r.add_argument("--inprocess", action="store_true", help="run in this process (lockstep, no Zenoh, no MCAP)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    sub.add_parser("agent", help="run one robot process (see copath agent --help)", add_help=False)
    sub.add_parser("sim", help="run the simulator process (see copath sim --help)", add_help=False)
    i = sub.add_parser("info", help="summarise a run log")
    i.add_argument("log")
    i.add_argument("--json", action="store_true")
    i.add_argument("--scenario", action="store_true", help="also print the recorded scenario")
    mt = sub.add_parser("metrics", help="recompute metrics.json from a run log (from the truth it recorded)")
    mt.add_argument("log")
    mt.add_argument("--out", help="write metrics.json here [print it]")
    rp = sub.add_parser("replay", help="republish a run log on Zenoh with its original timing")
    rp.add_argument("log")
    rp.add_argument("--speed", type=float, default=1.0)
    rp.add_argument("--run-id", help="publish under this run id instead of the recorded one")
    rp.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT")
    rp.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT")
    sub.add_parser("scenarios", help="list the scenarios in configs/")
    v = sub.add_parser("validate", help="check scenario files (controller parameters included) and print "
                       "every problem; starts nothing")
    v.add_argument("configs", nargs="+", metavar="CONFIG")
    sub.add_parser("controllers", help="list the controller types (built-in and installed)")
    b = sub.add_parser("bench", help="benchmarks that print figures", add_help=False)
    b.add_argument("what", choices=("solve", "dmpc"))
    return p


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "agent":
        from agent.node import main as agent_main

        return agent_main(argv[1:])
    if argv and argv[0] == "sim":
        from sim.node import main as sim_main

        return sim_main(argv[1:])
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    parser = build_parser()
    if argv and argv[0] == "bench":
        args, rest = parser.parse_known_args(argv)
        return _cmd_bench(args, rest)
    args = parser.parse_args(argv)
    handlers = {"run": _cmd_run, "info": _cmd_info, "metrics": _cmd_metrics, "replay": _cmd_replay, "scenarios": _cmd_scenarios,
                "validate": _cmd_validate, "controllers": _cmd_controllers}
    return handlers[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
