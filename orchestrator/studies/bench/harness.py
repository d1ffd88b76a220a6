"""``copath bench``: one harness for the figures of speed and scale (docs/reference/performance.md).

    copath bench solve    [--controllers ...] [--horizons ...] [--json]   MPC solve times vs horizon
    copath bench dmpc     [--robots 3 8 16] [--json]                      DMPC update period, realtime fleets
    copath bench fleet    [--scenarios e5.4 e6.1] [--json]                lockstep over Zenoh vs in-process
    copath bench scale    [--robots 8 16 32 64 128] [--json]              realtime consensus fleets
    copath bench latency  [--robots 16] [--messages 100000] [--json]      neighbour latency, recorder rate
    copath bench secure   [--scenario e5.5] [--reps 3] [--json]           cost of secure mode (lockstep)
    copath bench peers    [--robots 6 16] [--reps 1] [--json]             copath against IR-SIM, alternately
    copath bench floor    [--robots 6] [--ticks 2000] [--fleet] [--json]  the floor of a lockstep fleet vs IR-SIM
    copath bench chaos    [--scenario e5.4-] [--minutes 10] [--json]      chaos soak: faults on a seeded schedule
    copath bench compare-metrics run OUT | compare BEFORE AFTER           in-process metrics key by key

Every subcommand prints a table (or, with ``--json``, one JSON document) and exits 1
when a run failed. The figures measured on the project's machine, with the machine's
load next to them, are in ``orchestrator/studies/bench/README.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time
from typing import Any, Callable, Iterator, Sequence

__all__ = ["SUBCOMMANDS", "main", "parser", "print_table", "machine", "emit", "number"]

SUBCOMMANDS = {
    "solve": "orchestrator.studies.bench.solve",
    "dmpc": "orchestrator.studies.bench.dmpc",
    "fleet": "orchestrator.studies.bench.fleet",
    "scale": "orchestrator.studies.bench.scale",
    "latency": "orchestrator.studies.bench.latency",
    "secure": "orchestrator.studies.bench.secure",
    "peers": "orchestrator.studies.bench.peers",
    "floor": "orchestrator.studies.bench.floor",
    "chaos": "orchestrator.studies.bench.chaos",
    "compare-metrics": "orchestrator.studies.bench.compare_metrics",
}
"""``copath bench WHAT``: the module of each subcommand (``add_arguments(parser)``, ``run(args)``)."""


def number(name: str, kind: type = float, least: float = 0.0, strict: bool = True) -> Callable[[str], Any]:
    """An argparse type for the option ``name``: a ``kind`` (float or int) above ``least`` (or at
    least ``least`` when not ``strict``), refused naming the option, the value and what is allowed."""
    what = "a whole number" if kind is int else "a number"
    bound = f"{'>' if strict else '>='} {least:g}"

    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} = {text!r} is not allowed; must be {what} {bound}") from None
        if not (v > least if strict else v >= least):
            raise argparse.ArgumentTypeError(f"{name} = {text!r} is not allowed; must be {bound}")
        return v
    return parse


def machine() -> dict[str, Any]:
    """What a figure depends on: cores and the load average when it was measured."""
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    return {"cores": os.cpu_count(), "load_1min": round(load[0], 2), "time": time.strftime("%Y-%m-%d %H:%M:%S")}


@contextlib.contextmanager
def scratch_dir(out: str | None, name: str) -> Iterator[pathlib.Path]:
    """The benchmark's run directory: ``out`` (kept) or a temporary one (removed afterwards)."""
    root = pathlib.Path(out) if out is not None else pathlib.Path(tempfile.mkdtemp(prefix=f"copath-bench-{name}-"))
    root.mkdir(parents=True, exist_ok=True)
    try:
        yield root
    finally:
        if out is None:
            shutil.rmtree(root, ignore_errors=True)


def print_table(rows: Sequence[dict[str, Any]], columns: Sequence[tuple[str, str, str]]) -> None:
    """Print ``rows`` with ``columns`` = (key, header, format spec); None prints as ``-``."""
    cells = [[("-" if r.get(k) is None else format(r[k], f)) for k, _, f in columns] for r in rows]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, (_, h, _) in enumerate(columns)]
    head = "  ".join(h.rjust(w) for (_, h, _), w in zip(columns, widths))
    print(head)
    print("-" * len(head))
    for c in cells:
        print("  ".join(x.rjust(w) for x, w in zip(c, widths)))


def emit(args: argparse.Namespace, result: dict[str, Any], table: Callable[[dict[str, Any]], None]) -> None:
    """Print ``result`` as JSON (``--json``) or as a table, with the machine's load."""
    result = {"machine": machine(), **result}
    if getattr(args, "json", False):
        print(json.dumps(result, indent=2))
        return
    table(result)
    m = result["machine"]
    print(f"({m['cores']} cores, load {m['load_1min']} at {m['time']})")


def parser(what: str) -> argparse.ArgumentParser:
    """The argument parser of ``copath bench WHAT``."""
    if what not in SUBCOMMANDS:
        raise ValueError(f"copath bench {what!r} is not allowed; allowed: {', '.join(SUBCOMMANDS)}")
    mod = importlib.import_module(SUBCOMMANDS[what])
    p = argparse.ArgumentParser(prog=f"copath bench {what}", description=(mod.__doc__ or "").split("\n")[0])
    mod.add_arguments(p)
    return p


def main(what: str, argv: Sequence[str]) -> int:
    """Run ``copath bench WHAT`` with its own arguments."""
    args = parser(what).parse_args(list(argv))
    from copath.scenario import ConfigError  # noqa: PLC0415

    try:
        return int(importlib.import_module(SUBCOMMANDS[what]).run(args) or 0)
    except ConfigError as exc:  # a bad --set or scenario: the key, the value, what is allowed
        print(f"copath bench {what}: {exc}", file=sys.stderr)
        return 2
