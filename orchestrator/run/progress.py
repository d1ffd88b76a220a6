"""The progress line of a run: sim time, real-time factor, messages/s and an ETA.

The run loop only reports numbers (:meth:`Progress.update`); a daemon thread draws the
line, so it keeps moving while nothing reports: while the processes start and their
solvers compile (before the first tick), or while an in-process run builds its
controllers. On a terminal the line redraws in place; otherwise (a log file, CI) one
line is printed per tenth of the run and every 10 s of start-up.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

__all__ = ["Progress"]


def _clock(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class Progress:
    """Progress of one run of ``duration_s`` simulated seconds.

    Parameters
    ----------
    duration_s : simulated duration of the run [s].
    enabled : draw nothing when False (``--quiet``).
    stream : where to draw (default stderr).
    starting : what the run does before its first tick (shown with the elapsed time).
    """

    def __init__(self, duration_s: float, *, enabled: bool = True, stream: TextIO | None = None,
                 starting: str = "starting", interval_s: float = 0.25) -> None:
        self.duration = float(duration_s)
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.starting = starting
        self.interval = interval_s
        self.t0 = time.monotonic()
        self.sim_t = 0.0
        self.messages = 0
        self._first_tick: float | None = None  # wall time of the first tick
        self._rate_window: list[tuple[float, int]] = []
        self._last_decile = -1
        self._last_start_note = 0.0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._width = 0

    # --- reporting (cheap; called from the run loop) ---
    def update(self, sim_t: float, messages: int | None = None) -> None:
        """The run reached ``sim_t`` [s] and has seen ``messages`` messages in all."""
        now = time.monotonic()
        with self._lock:
            if sim_t > 0 and self._first_tick is None:
                self._first_tick = now
                self._rate_window.clear()  # the rate counts from the first tick on
            self.sim_t = max(self.sim_t, float(sim_t))
            if messages is not None:
                self.messages = int(messages)
                self._rate_window.append((now, self.messages))
                while len(self._rate_window) > 2 and now - self._rate_window[0][0] > 1.0:
                    self._rate_window.pop(0)
        if not self.tty:
            self._maybe_print_line()

    # --- figures ---
    def figures(self) -> dict[str, float | None]:
        """Current sim time [s], wall time [s], real-time factor, messages/s and ETA [s]."""
        now = time.monotonic()
        with self._lock:
            sim_t, first = self.sim_t, self._first_tick
            window = list(self._rate_window)
        running = None if first is None else now - first
        rtf = sim_t / running if running and running > 0.05 and sim_t > 0 else None
        rate = None
        if len(window) >= 2 and window[-1][0] - window[0][0] > 0:
            rate = (window[-1][1] - window[0][1]) / (window[-1][0] - window[0][0])
        eta = (self.duration - sim_t) / rtf if rtf else None
        return {"sim_t": sim_t, "wall": now - self.t0, "rtf": rtf, "msgs_per_s": rate, "eta": eta}

    def line(self) -> str:
        f = self.figures()
        if self._first_tick is None:
            return f"  {self.starting} ... {_clock(f['wall'])}"
        frac = min(1.0, self.sim_t / self.duration) if self.duration > 0 else 1.0
        bar = "#" * int(20 * frac) + "-" * (20 - int(20 * frac))
        parts = [f"  [{bar}] {int(100 * frac):3d}%  {f['sim_t']:6.1f}/{self.duration:.1f} s sim"]
        parts.append(f"x{f['rtf']:.2f} real time" if f["rtf"] else "x- real time")
        if f["msgs_per_s"] is not None:
            parts.append(f"{f['msgs_per_s']:6.0f} msg/s")
        parts.append(f"ETA {_clock(f['eta'])}" if f["eta"] is not None else "ETA -")
        parts.append(f"wall {_clock(f['wall'])}")
        return "  ".join(parts)

    # --- drawing ---
    def _draw(self) -> None:
        text = self.line()
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def _maybe_print_line(self) -> None:
        if not self.enabled:
            return
        if self._first_tick is None:
            return
        frac = min(1.0, self.sim_t / self.duration) if self.duration > 0 else 1.0
        decile = int(frac * 10)
        if decile > self._last_decile:
            self._last_decile = decile
            self.stream.write(self.line().strip() + "\n")
            self.stream.flush()

    def _loop(self) -> None:
        while not self._stop.wait(self.interval):
            if self.tty:
                self._draw()
            elif self._first_tick is None and time.monotonic() - self._last_start_note >= 10.0:
                self._last_start_note = time.monotonic()
                self.stream.write(self.line().strip() + "\n")
                self.stream.flush()

    def start(self) -> "Progress":
        if self.enabled and self._thread is None:
            self._last_start_note = time.monotonic()
            self._thread = threading.Thread(target=self._loop, name="copath-progress", daemon=True)
            self._thread.start()
        return self

    def done(self) -> None:
        """Stop drawing; leave the final line on screen."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
            if self.tty:
                self._draw()
                self.stream.write("\n")
                self.stream.flush()

    def __enter__(self) -> "Progress":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.done()
