"""``copath bench peers``: copath against IR-SIM, the simulator users would pick instead, in one run.

    copath bench peers [--robots 6 16] [--reps 1] [--no-fleet] [--no-filter] [--json]

For each fleet size it runs, one after the other in this order and ``--reps`` times
(alternating, so a change of the machine's load hits both sides alike):

1. **IR-SIM** (``pip install 'copath[peers]'``, the ``ir-sim`` package): N diff-drive robots
   with its RVO behaviour, no sensors, no rendering (``headless``), step 0.1 s, 800 steps
   (80 s simulated), in this process. Its world file is written by this harness
   (:func:`irsim_world`): the robots start on a circle of radius 10 m and swap places
   across it at 0.25 m/s, so they are still moving at the last step (chosen: a robot that
   has arrived costs IR-SIM less, and copath's robots move for the whole run).
2. **copath in one process** (``orchestrator/run/inprocess.py``, the node code on the
   in-memory bus), with the scenario's safety filter (``--no-filter`` turns it off).
3. **copath lockstep over Zenoh** (one process per robot, the simulator and the recorder,
   as ``copath run``), unless ``--no-fleet``.

The copath scenarios: 6 robots is E5.4 as bundled (80 s); 16 robots is E5.4 grown to 16
(:func:`e54_sixteen`, chosen: E5.4's controller, gains, models and safety filter, the
column's 0.5 m spacing and chain graph, on a lemniscate with a = 4.0 m instead of 2.3 m so
the 7.5 m column is shorter than half the path and no two robots meet at the crossing).

Each side's real-time factor is simulated time / wall time of the whole run (IR-SIM's
``make`` and 800 steps; copath's building, running and metrics, as ``bench fleet``), and
each copath figure is divided by the IR-SIM figure of the same repetition; ``same, by CPU``
is the in-process ratio from CPU time per robot step (IR-SIM's over copath's), which a
loaded machine moves much less than wall time. ``agent CPU
ms/step`` is the fleet agents' CPU per lockstep step (p50 over agents, from their closing
accounts) and ``inproc CPU us/step`` this process's CPU per robot step in one process.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import pathlib
import sys
import time
import tomllib
from typing import Any

from orchestrator.studies.bench.harness import emit, print_table, scratch_dir

__all__ = ["add_arguments", "run", "irsim_world", "run_irsim", "e54_sixteen", "copath_scenario"]

STEP_S = 0.1
"""IR-SIM's step, E5.4's control period."""
STEPS = 800
"""IR-SIM's steps: 80 s simulated, E5.4's duration."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robots", type=int, nargs="+", default=[6, 16], choices=[6, 16], metavar="N",
                        help="fleet sizes: 6 (E5.4) and 16 (E5.4 grown to 16) [6 16]")
    parser.add_argument("--reps", type=int, default=1, metavar="K", help="repetitions of the IR-SIM / copath sequence [1]")
    parser.add_argument("--no-fleet", action="store_true", help="in-process only (no lockstep fleet over Zenoh)")
    parser.add_argument("--no-filter", action="store_true", help="copath with safety.enabled = false")
    parser.add_argument("--out", help="keep the fleet runs and IR-SIM's world files here (default: temporary)")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")


def irsim_world(n: int, steps_s: float = STEP_S) -> str:
    """IR-SIM's world file (YAML) for ``n`` diff-drive robots with RVO, nothing else.

    Chosen: a circle of radius 10 m (robots swap to the opposite point, 20 m at the RVO's
    0.25 m/s: the whole 80 s), disc radius 0.1 m (E5.4's unicycles), velocity limits wide
    enough that RVO's commands are never clipped (IR-SIM formats a warning for each clipped
    command, which would charge it for logging), collisions not checked against obstacles
    (there are none)."""
    return f"""world:
  height: 24
  width: 24
  step_time: {steps_s}
  sample_time: {steps_s}
  offset: [-12, -12]
  collision_mode: 'unobstructed'
  control_mode: 'auto'
robot:
  - number: {n}
    distribution: {{name: 'circle', radius: 10.0, center: [0, 0]}}
    kinematics: {{name: 'diff'}}
    shape: {{name: 'circle', radius: 0.1}}
    behavior: {{name: 'rvo', vxmax: 0.25, vymax: 0.25, acce: 0.3, factor: 1.0}}
    vel_min: [-1.0, -3.0]
    vel_max: [1.0, 3.0]
    arrive_mode: position
    goal_threshold: 0.05
"""


def run_irsim(n: int, root: pathlib.Path, steps: int = STEPS) -> dict[str, Any]:
    """Run IR-SIM's ``n``-robot world for ``steps`` steps; wall and CPU time of make + steps."""
    # IR-SIM prints its search for a plotting backend on stdout: keep stdout for the table or JSON
    with contextlib.redirect_stdout(sys.stderr):
        try:
            import irsim  # noqa: PLC0415
        except ImportError as exc:
            raise SystemExit("copath bench peers needs IR-SIM: pip install 'copath[peers]' (the ir-sim package)") from exc
        world = root / f"irsim-{n}.yaml"
        world.write_text(irsim_world(n))
        t0, c0 = time.perf_counter(), time.process_time()
        env = irsim.make(str(world), display=False, headless=True, log_level="ERROR")
        for _ in range(steps):
            env.step()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        moving = sum(1 for r in env.robot_list if not r.arrive_flag)
        env.end(0)
    sim_s = steps * STEP_S
    return {"irsim_sim_s": sim_s, "irsim_wall_s": round(wall, 3), "irsim_rtf": round(sim_s / wall, 2),
            "irsim_cpu_us_per_step": round(1e6 * cpu / (steps * n), 1), "irsim_moving_at_end": moving}


def e54_sixteen():
    """E5.4 grown to 16 robots (chosen; see the module's docstring)."""
    from copath.paths import lemniscate  # noqa: PLC0415

    from orchestrator.api import find_scenario  # noqa: PLC0415
    from orchestrator.run.validate import validate_table  # noqa: PLC0415

    src = find_scenario("e5.4-six-robots-lemniscate")
    raw = tomllib.loads(src.read_text())
    a = 4.0
    raw["paths"]["main"]["a"] = a
    path = lemniscate(a)
    model = dict(raw["robots"][0]["model"])
    n = 16
    robots = []
    for i in range(n):
        s_d = -0.5 * i
        x, y, th, _ = path.frame(s_d % path.length)
        # E5.4's initial errors, smaller: off the path across, along and in heading, alternating
        sign = 1.0 if i % 2 == 0 else -1.0
        robots.append({"name": f"r{i + 1}", "model": model, "path": "main",
                       "pose": [round(x + 0.1 * sign * math.sin(th), 3), round(y - 0.1 * sign * math.cos(th), 3),
                                round(th + 0.2 * sign, 3)],
                       "neighbours": [f"r{j + 1}" for j in (i - 1, i + 1) if 0 <= j < n],
                       "controller": {"s_d": s_d}})
    raw["robots"] = robots
    raw["id"] = "e5.4-sixteen-robots-lemniscate"
    raw["title"] = "E5.4 grown to 16 unicycles (bench peers)"
    raw.pop("targets", None)
    return validate_table(raw, base_dir=src.parent, source="bench peers: e5.4 grown to 16 robots")


def copath_scenario(n: int, no_filter: bool):
    from orchestrator import api  # noqa: PLC0415

    sc = api.load("e5.4-six-robots-lemniscate") if n == 6 else e54_sixteen()
    if no_filter:
        sc = api.load(sc, {"safety.enabled": False})
    return sc


def _measure(n: int, rep: int, args: argparse.Namespace, root: pathlib.Path) -> dict[str, Any]:
    from orchestrator.studies.bench.fleet import measure  # noqa: PLC0415

    row: dict[str, Any] = {"robots": n, "rep": rep + 1}
    row.update(run_irsim(n, root))
    sc = copath_scenario(n, args.no_filter)
    row["scenario"] = sc.id
    ns = argparse.Namespace(set=[], duration=None, no_inprocess=False, no_fleet=args.no_fleet)
    row.update(measure(sc, ns, root))
    row.pop("scenario", None)
    row["scenario"] = sc.id
    ir = row["irsim_rtf"]
    row["inproc_over_irsim"] = round(row["inproc_rtf"] / ir, 3) if row.get("inproc_rtf") else None
    row["fleet_over_irsim"] = round(row["fleet_rtf"] / ir, 3) if row.get("fleet_rtf") else None
    # the same ratio from CPU time per robot step, which moves much less with the machine's load
    cpu = row.get("inproc_cpu_us_per_step")
    row["inproc_over_irsim_cpu"] = round(row["irsim_cpu_us_per_step"] / cpu, 3) if cpu else None
    return row


def _table(result: dict[str, Any]) -> None:
    print("IR-SIM (RVO, one process) and copath (in one process; lockstep over Zenoh), run alternately; "
          "rtf = simulated / wall")
    print_table(result["runs"], [
        ("robots", "robots", "d"), ("rep", "rep", "d"), ("irsim_rtf", "IR-SIM rtf", ".1f"),
        ("inproc_rtf", "inproc rtf", ".1f"), ("inproc_over_irsim", "inproc/IR-SIM", ".2f"),
        ("inproc_over_irsim_cpu", "same, by CPU", ".2f"),
        ("fleet_rtf", "lockstep rtf", ".1f"), ("fleet_over_irsim", "lockstep/IR-SIM", ".2f"),
        ("irsim_cpu_us_per_step", "IR-SIM CPU us/robot step", ".0f"),
        ("inproc_cpu_us_per_step", "inproc CPU us/robot step", ".0f"),
        ("agent_cpu_ms_per_step", "agent CPU ms/step", ".3f"), ("fleet_wall_s", "lockstep s", ".2f")])
    for r in result["runs"]:
        if not r["ok"]:
            print(f"{r['scenario']}: fleet run failed: {r.get('reason')}")
    print(f"copath scenarios: {', '.join(sorted({r['scenario'] for r in result['runs']}))}"
          f"{' (safety filter off)' if result.get('no_filter') else ''}")


def run(args: argparse.Namespace) -> int:
    with scratch_dir(args.out, "peers") as root:
        rows = [_measure(n, rep, args, root) for rep in range(args.reps) for n in args.robots]
    emit(args, {"runs": rows, "no_filter": args.no_filter}, _table)
    return 0 if all(r["ok"] for r in rows) else 1
