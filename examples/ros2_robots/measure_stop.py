"""Measure zero-on-exit: how soon after Ctrl-C every robot receives a zero Twist (docs/reference/ros2.md).

Starts the example robots (recording every Twist they receive) and ``copath run`` of a
scenario over them, interrupts the run once every robot moves, and prints per robot the
delay from the signal to its first zero Twist and how long zeros kept arriving::

    python examples/ros2_robots/measure_stop.py e5.5 --repeat 3

Uses its own ROS_DOMAIN_ID unless one is set, and discovery on this host only.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent


def once(config: str, sig: int, tmp: pathlib.Path, env: dict) -> dict[str, tuple[float, float]]:
    record = tmp / "twists.jsonl"
    record.unlink(missing_ok=True)
    robots = subprocess.Popen([sys.executable, str(HERE / "ros2_robots.py"), config, "--record", str(record)],
                              env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    run = subprocess.Popen([sys.executable, "-m", "orchestrator", "run", config, "--set", "world.backend=ros2",
                            "--clock", "realtime", "--out", str(tmp / "run"), "-q", "--no-plots"], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        names: set[str] = set()
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and run.poll() is None:
            if record.exists():
                rows = [json.loads(x) for x in record.read_text().splitlines() if x.strip()]
                moving = {r["robot"] for r in rows if any(r["cmd"])}
                names = {r["robot"] for r in rows}
                if moving and moving == names:
                    break
            time.sleep(0.2)
        time.sleep(1.0)
        t_sig = time.time()
        run.send_signal(sig)
        run.wait(timeout=60)
        time.sleep(0.8)
    finally:
        for p in (run, robots):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM) if p is robots else p.kill()
                p.wait(timeout=10)
    rows = [json.loads(x) for x in record.read_text().splitlines() if x.strip() and json.loads(x)["t"] >= t_sig]
    out = {}
    for n in sorted(names):
        zeros = [r["t"] for r in rows if r["robot"] == n and not any(r["cmd"])]
        out[n] = (zeros[0] - t_sig, zeros[-1] - zeros[0]) if zeros else (float("nan"), 0.0)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("config", nargs="?", default="e5.5")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--signal", choices=("INT", "TERM"), default="INT")
    args = p.parse_args()
    env = dict(os.environ)
    env.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(HERE.parents[1]), env.get("PYTHONPATH", "")) if p)
    delays = []
    with tempfile.TemporaryDirectory() as d:
        for i in range(args.repeat):
            res = once(args.config, getattr(signal, f"SIG{args.signal}"), pathlib.Path(d), env)
            for n, (first, held) in res.items():
                delays.append(first)
                print(f"run {i + 1}: {n}: first zero Twist {1e3 * first:.1f} ms after SIG{args.signal}, "
                      f"zeros for {held:.2f} s")
    delays.sort()
    print(f"zero-on-exit over {len(delays)} robot stops: median {1e3 * delays[len(delays) // 2]:.1f} ms, "
          f"max {1e3 * delays[-1]:.1f} ms; load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
