"""A controller that fails is seen: one terminal line per robot, from the run's event stream.

When a controller's ``step()`` raises (or returns an invalid command), the robot's runtime
(``agent/runtime.py``) stops the robot for that step, counts it (telemetry
``controller_error``, ``metrics.json`` ``controller_errors``) and, the first time only,
publishes a ``controller_error`` event with the robot, the time, the exception and its
traceback. :class:`FailureReporter` subscribes to the run's events and prints that event
as one line on the terminal: in a fleet the orchestrator does (the robots' own output goes
to their log files, which hold the traceback once), and in one process the in-process
loop does (the traceback then goes to ``<out>/logs/<robot>.log`` when the run has an
output directory, and is in the run log's event either way). docs/reference/controllers.md, "When
step() fails".
"""

from __future__ import annotations

import pathlib
import sys
import threading
from typing import Any, TextIO

from copath.wire.messages import Event

__all__ = ["FailureReporter", "failure_line"]


def failure_line(ev: Event, log: str | pathlib.Path | None = None) -> str:
    """One line for a ``controller_error`` event: robot, sim time, exception, where the
    traceback is."""
    d = ev.detail
    where = f"traceback in {log}" if log is not None else "traceback in the run log's controller_error event"
    return (f"copath: robot {ev.source}: controller step failed at t={ev.t:.2f} s: {d.get('error', '?')}: "
            f"{d.get('message', '')} (the robot stands still at each failing step, counted as "
            f"controller_errors; {where})")


class FailureReporter:
    """Subscriber callback ``(key, record)``: prints the first ``controller_error`` event of
    each robot as one line (:func:`failure_line`) on ``stream`` (default: stderr).

    ``log_dir``: where the robots' logs are (named in the line). With ``write_logs`` (one
    process, where no agent writes a log) the event's traceback is written there,
    ``<robot>.log``."""

    def __init__(self, stream: TextIO | None = None, log_dir: str | pathlib.Path | None = None,
                 write_logs: bool = False) -> None:
        self.stream = stream
        self.log_dir = None if log_dir is None else pathlib.Path(log_dir)
        self.write_logs = write_logs
        self.lines: list[str] = []
        """Every line printed, in order."""
        self._seen: set[str] = set()
        self._lock = threading.Lock()  # Zenoh callbacks run on several threads

    def __call__(self, key: str, rec: Any) -> None:
        if not isinstance(rec, Event) or rec.what != "controller_error":
            return
        with self._lock:
            if rec.source in self._seen:
                return
            self._seen.add(rec.source)
        log = None if self.log_dir is None else self.log_dir / f"{rec.source}.log"
        if log is not None and self.write_logs:
            try:
                log.parent.mkdir(parents=True, exist_ok=True)
                with log.open("a") as fh:
                    fh.write(f"robot {rec.source}: controller step failed at t={rec.t:.3f} s (tick "
                             f"{rec.detail.get('k')}); later failures are counted (controller_errors), "
                             f"not logged\n{rec.detail.get('traceback', '')}")
            except OSError:
                log = None
        line = failure_line(rec, log)
        self.lines.append(line)
        stream = self.stream if self.stream is not None else sys.stderr
        tty = bool(getattr(stream, "isatty", lambda: False)())
        stream.write(("\r\033[K" if tty else "") + line + "\n")  # over a progress line being drawn
        stream.flush()
