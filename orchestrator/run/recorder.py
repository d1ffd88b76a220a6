"""The recording side of a fleet run: the run's log written from everything the router
hears, and what is fed from the same stream while the run goes on (the Foxglove views in
the log and on a live server, the ROS 2 mirror, the one-line report of a controller's
failure).

The log itself is ``orchestrator/log/writer.py``'s :class:`Recorder`, which knows nothing
of views: :class:`RunRecorder` adds them (``orchestrator/view/foxglove.py``)."""

from __future__ import annotations

import json
import logging
import os
import pathlib
import sys
import time

from copath.scenario import Scenario
from copath.wire.keys import Keys
from copath.wire.session import ZenohLink

from orchestrator.log.writer import Recorder, fault_metadata
from orchestrator.version import software_version
from orchestrator.run.failures import FailureReporter

logger = logging.getLogger(__name__)

__all__ = ["RunRecorder", "run_metadata"]


def run_metadata(scenario: Scenario, run_id: str, secure: bool) -> dict[str, dict[str, str]]:
    """The MCAP metadata of a fleet run: the effective scenario, the software, the faults injected."""
    raw = dict(scenario.raw)
    raw["_source"] = scenario.source
    metadata = {
        "scenario": {"json": json.dumps(raw), "id": scenario.id, "source": scenario.source},
        "copath": {"version": software_version(), "run_id": run_id, "clock": scenario.run.clock,
                   "seed": str(scenario.run.seed), "robots": ",".join(scenario.robot_names),
                   "python": sys.version.split()[0]},
        "faults": fault_metadata(scenario),
    }
    if scenario.world.ros2:  # the world records are what the robots reported (docs/reference/ros2.md)
        metadata["world"] = {"backend": "ros2", "truth": "poses reported by the robots, not ground truth",
                             "ros_domain_id": os.environ.get("ROS_DOMAIN_ID", "0")}
    metadata["copath"]["secure"] = str(secure)
    return metadata


class RunRecorder:
    """The run's log and its live views. Made in two steps: the constructor opens the live
    outlets (a busy port fails the run before anything starts), :meth:`start` the log on
    the router, before any process of the run is started."""

    def __init__(self, scenario: Scenario, keys: Keys, out: pathlib.Path, live_port: int | None = None,
                 ros2_view: bool = False) -> None:
        self.scenario, self.keys, self.out = scenario, keys, pathlib.Path(out)
        self.live = self._tail = None
        if live_port is not None:
            from orchestrator.view.foxglove import TOPICS  # noqa: PLC0415
            from orchestrator.view.live import LiveViz, LogTail  # noqa: PLC0415

            self.live = LiveViz(live_port)
            self.live.advertise(TOPICS)
            self._tail = LogTail(self.out / "logs", self.live).start()  # process log lines, live
            logger.info("live views on %s (Foxglove: Open connection -> Foxglove WebSocket)", self.live.url)
        self._mirror = None
        if ros2_view:  # RViz2 and ros2 topic echo see the run (docs/reference/ros2.md); before the router opens
            from orchestrator.view.ros2 import Ros2Mirror  # noqa: PLC0415

            self._mirror = Ros2Mirror(scenario, keys)
        self.log: Recorder | None = None
        """The run's log (``run.mcap``), once :meth:`start` opened it."""
        self._views = None

    def start(self, router: ZenohLink, metadata: dict[str, dict[str, str]]) -> Recorder:
        """Open ``run.mcap`` with ``metadata``, add the Foxglove views, and record everything
        ``router`` hears under the run's keys (with each sender's sequence numbers)."""
        from orchestrator.view.foxglove import RecordedViews  # noqa: PLC0415

        self.log = Recorder(self.out / "run.mcap", self.keys, metadata)
        self._views = RecordedViews(self.log, self.scenario, live=self.live)
        router.subscribe_raw(self.keys.all, self.log.write, attachment=True)
        if self._mirror is not None:
            router.subscribe_raw(self.keys.all, self._mirror.write)
        # the first controller failure of each robot, one line here (its traceback is in its log)
        router.subscribe(self.keys.event("*"), FailureReporter(log_dir=self.out / "logs"))
        return self.log

    def await_accounts(self, expected: set[str]) -> None:
        """Wait for the closing accounts (``stats``) of ``expected`` still in flight through
        the router: 3 s, longer while records keep arriving (at most 15 s)."""
        rec = self.log
        deadline, hard, seen = time.monotonic() + 3.0, time.monotonic() + 15.0, rec.count
        while time.monotonic() < deadline and not expected <= set(rec.stats):
            time.sleep(0.02)
            if rec.count != seen:  # a busy router is still forwarding: keep waiting a while
                seen, deadline = rec.count, min(hard, max(deadline, time.monotonic() + 1.0))

    def finish(self, ok: bool, reason: str) -> None:
        """Close the run's log with its outcome, once the router is closed: the processes'
        log lines go in as a view, then the live outlets close."""
        if self._mirror is not None:
            self._mirror.close()
        if self.log is not None:
            if self._views is not None:
                self._views.add_process_logs(self.out / "logs")
            self.log.finish({"outcome": {"ok": str(ok), "reason": reason}})
        if self.live is not None:
            self._tail.stop()
            self.live.close()
