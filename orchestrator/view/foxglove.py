"""Foxglove views of a run, built from its records with Foxglove's own message types.

:class:`VizBuilder` turns the records of a run (the same stream the recorder writes and
``copath replay`` reads back) into ``foxglove-sdk`` messages (``foxglove.messages``):

===================  ======================  ============================================
topic                Foxglove type           content
===================  ======================  ============================================
``/viz/scene``       ``foxglove.SceneUpdate``  paths (once), robots as footprint discs with
                                             heading arrows, obstacles (Figs 5.10, 6.2)
``/viz/robots``      ``foxglove.PosesInFrame`` true poses
``/viz/plans``       ``foxglove.SceneUpdate``  each controller's reference point and the
                                             predicted horizons it broadcasts: the DMPC
                                             assumed trajectory (Algorithm 5.1, step 2) and
                                             the leader's planned speeds (Sec. 5.3); a
                                             ``plan`` ([[x, y, ...], ...]) in a controller's
                                             telemetry takes precedence
``/viz/formation``   ``foxglove.SceneUpdate``  formation targets (followers' references,
                                             Ch. 6 target positions) with the task each
                                             robot is assigned
``/viz/ranges``      ``foxglove.SceneUpdate``  range-sensor rays (Sec. 4.4.2)
``/viz/links``       ``foxglove.SceneUpdate``  communication links up (green), whose latest
                                             message was lost (orange), cut by a partition
                                             (red), Def. 10
``/viz/events``      ``foxglove.Log``          fault windows opening and closing, process
                                             events, the end of the run
``/viz/log``         ``foxglove.Log``          every process's log lines
===================  ======================  ============================================

Messages carry simulated time in their ``timestamp`` fields; the sink decides the log
time. Sinks: :class:`McapVizSink` writes them as protobuf with Foxglove's schema into the
run's MCAP (:class:`RecordedViews`, a tap on ``orchestrator/log/writer.py``'s recorder, which
knows nothing of views); ``orchestrator/view/live.py`` serves them over the
Foxglove WebSocket protocol. The choice of protobuf over JSON is in ``docs/reference/viewing.md``.
These channels are derived data, outside the run's key space, and not counted as messages.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import pathlib
import re
import threading
import time
from typing import Any, Callable, Iterator

import numpy as np
import foxglove
from foxglove import messages as fm

from copath.scenario import Scenario
from copath.wire.faults import LinkFaults
from copath.wire.keys import Keys
from copath.wire.messages import End, Event, Obs, PeerEnvelope, Telemetry, Truth

from orchestrator.log.plans import plan_positions

__all__ = ["TOPICS", "VizBuilder", "FaultReplay", "McapVizSink", "RecordedViews", "views_tap", "log_line",
           "process_log_messages", "foxglove_layout"]

FRAME = "world"

TOPICS: dict[str, type] = {
    "/viz/scene": fm.SceneUpdate,
    "/viz/robots": fm.PosesInFrame,
    "/viz/plans": fm.SceneUpdate,
    "/viz/formation": fm.SceneUpdate,
    "/viz/ranges": fm.SceneUpdate,
    "/viz/links": fm.SceneUpdate,
    "/viz/events": fm.Log,
    "/viz/log": fm.Log,
}
"""Every Foxglove topic a run can carry and its message type."""

_PALETTE = [(0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
            (0.58, 0.4, 0.74), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5)]
_FOREVER = fm.Duration(sec=0, nsec=0)


def _time(t: float) -> fm.Timestamp:
    sec = int(math.floor(t))
    return fm.Timestamp(sec, int(round((t - sec) * 1e9)) % 1_000_000_000)


def _pose(x: float = 0.0, y: float = 0.0, th: float = 0.0, z: float = 0.0) -> fm.Pose:
    return fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=float(z)),
                   orientation=fm.Quaternion(x=0.0, y=0.0, z=math.sin(th / 2), w=math.cos(th / 2)))


def _rgba(rgb, a: float = 1.0) -> fm.Color:
    return fm.Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


def _color(i: int, a: float = 1.0) -> fm.Color:
    return _rgba(_PALETTE[i % len(_PALETTE)], a)


def _points(xy) -> list[fm.Point3]:
    return [fm.Point3(x=float(a), y=float(b), z=0.0) for a, b in np.asarray(xy, dtype=float).reshape(-1, 2)]


def _line(xy, color: fm.Color, thickness: float = 2.0, closed: bool = False) -> fm.LinePrimitive:
    kind = fm.LinePrimitiveLineType.LineLoop if closed else fm.LinePrimitiveLineType.LineStrip
    return fm.LinePrimitive(type=kind, pose=_pose(), thickness=thickness, scale_invariant=True,
                            points=_points(xy), color=color)


def _segments(pairs, color: fm.Color, thickness: float = 2.0) -> fm.LinePrimitive:
    """Disjoint segments [(p, q), ...] as one LineList."""
    pts = [c for p, q in pairs for c in (p, q)]
    return fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, pose=_pose(), thickness=thickness,
                            scale_invariant=True, points=_points(pts) if pts else [], color=color)


def _entity(t: float, ident: str, **prims) -> fm.SceneEntity:
    return fm.SceneEntity(timestamp=_time(t), frame_id=FRAME, id=ident, lifetime=_FOREVER, **prims)


def _is_points(v) -> bool:
    return isinstance(v, list) and len(v) > 1 and all(isinstance(q, list) and len(q) >= 2 for q in v)


def _log(t: float, level: fm.LogLevel, name: str, message: str) -> fm.Log:
    return fm.Log(timestamp=_time(t), level=level, message=message, name=name)


def communication_links(scenario: Scenario, t: float, poses: dict,
                        edges: list[tuple[str, str]] | None = None) -> tuple[list, list]:
    """Links (a, b) up and cut by a partition at ``t``: the graph edges, or the pairs
    within ``network.range_m`` of each other (Def. 10); only robots with a pose count.
    The one definition behind the Foxglove link view and the snapshot figures."""
    net = scenario.network
    if net.range_m > 0:
        names = [n for n in scenario.robot_names if n in poses]
        pairs = [(a, b) for k, a in enumerate(names) for b in names[k + 1:]
                 if math.dist(poses[a][:2], poses[b][:2]) <= net.range_m]
    else:
        pairs = [tuple(e) for e in (scenario.edges() if edges is None else edges) if e[0] in poses and e[1] in poses]
    cut = {frozenset(link) for p in net.partitions if p.start_s <= t < p.end_s for link in p.links}
    up = [e for e in pairs if frozenset(e) not in cut]
    down = [e for e in pairs if frozenset(e) in cut]
    return up, down


class FaultReplay:
    """The fault layer's decisions, recovered from the published peer messages.

    The fault layer (``copath.wire.faults``) draws from one seeded stream per directed link,
    once per message in the sender's order, so replaying it on the messages of the log
    gives every receiver's decision without the receivers' help (docs/reference/viewing.md, dropped messages reconstructed (V1)).
    """

    def __init__(self, scenario: Scenario) -> None:
        net = scenario.network
        self.active = net.loss > 0 or net.burst_p_gb > 0 or bool(net.partitions)
        self._faults = {r.name: LinkFaults(net, scenario.run.seed, r.name) for r in scenario.robots} \
            if self.active else {}
        self._hears = {r.name: None if net.range_m > 0 else set(r.neighbours) for r in scenario.robots}

    def decide(self, rel: str, env: PeerEnvelope) -> list[tuple[str, str | None]]:
        """(receiver, None | "loss" | "partition") for every robot that receives ``env``
        (published on the run-relative key ``rel``); call in each sender's order."""
        out = []
        for r, faults in self._faults.items():
            hears = self._hears[r]
            if r == env.sender or (hears is not None and env.sender not in hears):
                continue
            if not (rel.endswith("/all") or rel.endswith(f"/to/{r}")):
                continue
            before = faults.partitioned
            if faults.release_time(env.sender, env.stamp) is None:
                out.append((r, "partition" if faults.partitioned > before else "loss"))
            else:
                out.append((r, None))
        return out


class VizBuilder:
    """The Foxglove views of one run, fed record by record.

    Per-robot state (latest telemetry, broadcast plan, ranges) is kept between truth
    ticks; each :class:`Truth` record yields one frame on every scene topic, so every
    view advances with the simulator's tick.
    """

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        self.scenario = scenario
        self.keys = keys
        self.names = list(scenario.robot_names)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.radii = {r.name: r.model.radius for r in scenario.robots}
        self.paths = {r.name: scenario.paths.get(r.path) if r.path else None for r in scenario.robots}
        self.edges = scenario.edges()
        self.dt = scenario.run.dt
        self.telemetry: dict[str, dict[str, Any]] = {}
        self.plans: dict[str, np.ndarray] = {}
        self.ranges: dict[str, list[float]] = {}
        self._active_partitions: set[int] = set()
        self.faults = FaultReplay(scenario)
        self._lost: dict[frozenset, float] = {}  # link -> stamp of its last message lost to faults
        self._angles = None
        if scenario.sensors.enabled:
            self._angles = scenario.sensors.angles()

    # ------------------------------------------------------------------ static
    def static(self) -> list[tuple[str, Any]]:
        """The scenario's paths as line strips on ``/viz/scene`` (kept until replaced)."""
        lines = []
        for path in self.scenario.paths.values():
            s = np.linspace(0.0, path.length, max(50, int(path.length / 0.02)))
            lines.append(_line(path.pos(s), fm.Color(r=0.6, g=0.6, b=0.6, a=0.8), 2.0, closed=path.closed))
        return [("/viz/scene", fm.SceneUpdate(entities=[_entity(0.0, "paths", lines=lines)]))]

    # ------------------------------------------------------------------ records
    def feed(self, key: str, rec: Any) -> list[tuple[str, Any]]:
        """The Foxglove messages ``rec`` (published on ``key``) gives rise to."""
        if isinstance(rec, Telemetry):
            self.telemetry[self.keys.relative(key).split("/")[1]] = rec.data
        elif isinstance(rec, PeerEnvelope):
            for receiver, outcome in self.faults.decide(self.keys.relative(key), rec):
                if outcome == "loss":
                    self._lost[frozenset((rec.sender, receiver))] = rec.stamp
            plan = self._plan(rec)
            if plan is not None:
                self.plans[rec.sender] = plan
        elif isinstance(rec, Obs):
            if rec.ranges is not None:
                self.ranges[self.keys.relative(key).split("/")[1]] = rec.ranges
        elif isinstance(rec, Truth):
            return self.frame(rec)
        elif isinstance(rec, Event):
            detail = json.dumps(rec.detail, default=str) if rec.detail else ""
            return [("/viz/events", _log(rec.t, fm.LogLevel.Warning, rec.source, f"{rec.what} {detail}".strip()))]
        elif isinstance(rec, End):
            level = fm.LogLevel.Info if rec.ok else fm.LogLevel.Error
            return [("/viz/events", _log(rec.t, level, "sim", f"end of run at t={rec.t:.2f} s: {rec.reason}"))]
        return []

    def _plan(self, env: PeerEnvelope) -> np.ndarray | None:
        """Predicted horizon of a broadcast plan as (N, 2) positions on the sender's path."""
        return plan_positions(self.paths.get(env.sender), env)

    def frame(self, truth: Truth) -> list[tuple[str, Any]]:
        """One frame of every scene view at the truth tick."""
        t = truth.t
        poses = {n: p for n, p in zip(truth.names, truth.poses)}
        out: list[tuple[str, Any]] = [("/viz/scene", self._scene(truth)),
                                      ("/viz/robots", fm.PosesInFrame(timestamp=_time(t), frame_id=FRAME,
                                                                      poses=[_pose(*p[:3]) for p in truth.poses]))]
        out.append(("/viz/plans", self._plans(t)))
        out.append(("/viz/formation", self._formation(t, poses)))
        if self._angles is not None:
            out.append(("/viz/ranges", self._rays(t, poses)))
        if len(self.names) > 1:
            out.append(("/viz/links", self._links(t, poses)))
        out += self._partition_events(t)
        return out

    def _scene(self, truth: Truth) -> fm.SceneUpdate:
        cyl, arrows, lines = [], [], []
        for n, p in zip(truth.names, truth.poses):
            i = self.index.get(n, 0)
            r = self.radii.get(n, 0.1)
            cyl.append(fm.CylinderPrimitive(pose=_pose(p[0], p[1], p[2]), size=fm.Vector3(x=2 * r, y=2 * r, z=0.05),
                                            bottom_scale=1.0, top_scale=1.0, color=_color(i, 0.8)))
            arrows.append(fm.ArrowPrimitive(pose=_pose(p[0], p[1], p[2], 0.05), shaft_length=1.5 * r,
                                            shaft_diameter=0.3 * r, head_length=0.6 * r, head_diameter=0.7 * r,
                                            color=_color(i)))
        for poly in truth.obstacles or []:
            lines.append(_line(poly, fm.Color(r=0.1, g=0.1, b=0.1, a=1.0), 3.0, closed=True))
        return fm.SceneUpdate(entities=[_entity(truth.t, "world", cylinders=cyl, arrows=arrows, lines=lines)])

    def _plans(self, t: float) -> fm.SceneUpdate:
        entities = []
        for n in self.names:
            i = self.index[n]
            lines, spheres, arrows = [], [], []
            tel = self.telemetry.get(n, {})
            plan = self.plans.get(n)
            if _is_points(tel.get("plan")):  # a predicted horizon the controller reports itself
                plan = np.asarray([q[:2] for q in tel["plan"]], dtype=float)
            if plan is not None and len(plan) > 1:
                lines.append(_line(plan, _color(i, 0.9), 4.0))
            ref = tel.get("ref")
            if ref is not None and len(ref) >= 2:
                d = 0.6 * self.radii.get(n, 0.1)
                spheres.append(fm.SpherePrimitive(pose=_pose(ref[0], ref[1]), size=fm.Vector3(x=d, y=d, z=d),
                                                  color=_color(i, 0.5)))
                if len(ref) >= 3:
                    arrows.append(fm.ArrowPrimitive(pose=_pose(ref[0], ref[1], ref[2]), shaft_length=d,
                                                    shaft_diameter=0.2 * d, head_length=0.5 * d,
                                                    head_diameter=0.5 * d, color=_color(i, 0.5)))
            entities.append(_entity(t, f"plan/{n}", lines=lines, spheres=spheres, arrows=arrows))
        return fm.SceneUpdate(entities=entities)

    def _formation(self, t: float, poses: dict) -> fm.SceneUpdate:
        segs, spheres, texts = [], [], []
        for n in self.names:
            tel = self.telemetry.get(n, {})
            target = tel.get("target")
            if target is None and tel.get("formation_error") is not None:
                target = tel.get("ref")
            p = poses.get(n)
            if p is None:
                continue
            if target is not None and len(target) >= 2:
                segs.append((p[:2], target[:2]))
                d = 0.5 * self.radii.get(n, 0.1)
                spheres.append(fm.SpherePrimitive(pose=_pose(target[0], target[1]), size=fm.Vector3(x=d, y=d, z=d),
                                                  color=_color(self.index[n], 0.7)))
            if tel.get("task") is not None:
                texts.append(fm.TextPrimitive(pose=_pose(p[0], p[1], 0.0, 0.2), billboard=True, font_size=12.0,
                                              scale_invariant=True, color=fm.Color(r=0.0, g=0.0, b=0.0, a=1.0),
                                              text=f"{n}: task {tel['task']}"))
        lines = [_segments(segs, fm.Color(r=0.3, g=0.3, b=0.3, a=0.8), 1.0)] if segs else []
        return fm.SceneUpdate(entities=[_entity(t, "formation", lines=lines, spheres=spheres, texts=texts)])

    def _rays(self, t: float, poses: dict) -> fm.SceneUpdate:
        segs = []
        for n, ranges in self.ranges.items():
            p = poses.get(n)
            if p is None:
                continue
            a = p[2] + self._angles[: len(ranges)]
            r = np.asarray(ranges, dtype=float)
            r = np.where(np.isfinite(r), r, self.scenario.sensors.max_range_m)
            ends = np.stack([p[0] + r * np.cos(a), p[1] + r * np.sin(a)], axis=-1)
            segs += [(p[:2], e) for e in ends]
        lines = [_segments(segs, fm.Color(r=0.9, g=0.6, b=0.0, a=0.7), 1.0)] if segs else []
        return fm.SceneUpdate(entities=[_entity(t, "ranges", lines=lines)])

    def communication_graph(self, t: float, poses: dict) -> tuple[list, list]:
        """Links up and cut at ``t`` (:func:`communication_links`)."""
        return communication_links(self.scenario, t, poses, self.edges)

    def _links(self, t: float, poses: dict) -> fm.SceneUpdate:
        up, down = self.communication_graph(t, poses)
        # a link whose latest message (either way) was lost to loss or bursts shows orange
        recent = t - 1.5 * self.dt
        lost = [e for e in up if self._lost.get(frozenset(e), -math.inf) >= recent]
        up = [e for e in up if e not in lost]
        seg = lambda links: [(poses[a][:2], poses[b][:2]) for a, b in links if a in poses and b in poses]  # noqa: E731
        lines = [_segments(seg(up), fm.Color(r=0.1, g=0.7, b=0.2, a=0.8), 1.5)]
        if lost:
            lines.append(_segments(seg(lost), fm.Color(r=1.0, g=0.55, b=0.0, a=0.9), 2.0))
        if down:
            lines.append(_segments(seg(down), fm.Color(r=0.9, g=0.1, b=0.1, a=0.9), 3.0))
        return fm.SceneUpdate(entities=[_entity(t, "links", lines=lines)])

    def _partition_events(self, t: float) -> list[tuple[str, Any]]:
        out = []
        for i, p in enumerate(self.scenario.network.partitions):
            active = p.start_s <= t < p.end_s
            links = ", ".join(f"{a}-{b}" for a, b in p.links)
            if active and i not in self._active_partitions:
                self._active_partitions.add(i)
                out.append(("/viz/events", _log(t, fm.LogLevel.Warning, "faults",
                                                f"partition {i} cuts {links} from t={p.start_s:g} s")))
            elif not active and i in self._active_partitions:
                self._active_partitions.discard(i)
                out.append(("/viz/events", _log(t, fm.LogLevel.Info, "faults", f"partition {i} over: {links} up")))
        return out


_LINE = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) (\S+) (DEBUG|INFO|WARNING|ERROR|CRITICAL) (.*)$")
_LEVELS = {"DEBUG": fm.LogLevel.Debug, "INFO": fm.LogLevel.Info, "WARNING": fm.LogLevel.Warning,
           "ERROR": fm.LogLevel.Error, "CRITICAL": fm.LogLevel.Fatal}


def log_line(raw: str, name: str, last_ns: int) -> tuple[int, fm.Log]:
    """One line of a process log as (wall time [ns], ``foxglove.Log``).

    Lines in the processes' logging format (``asctime name LEVEL message``, local time)
    keep their time and level; other lines (tracebacks, solver output) take ``last_ns``
    (the time of the line before them) and the level Unknown.
    """
    m = _LINE.match(raw)
    if m:
        stamp = _dt.datetime.strptime(m.group(1), "%Y-%m-%d %H:%M:%S").timestamp()
        t = int(stamp * 1e9) + int(m.group(2)) * 1_000_000
        level, msg = _LEVELS[m.group(4)], m.group(5)
    else:
        t, level, msg = last_ns, fm.LogLevel.Unknown, raw
    return t, fm.Log(timestamp=fm.Timestamp(t // 1_000_000_000, t % 1_000_000_000), level=level, message=msg,
                     name=name, file=f"{name}.log")


def process_log_messages(log_dir: str | pathlib.Path, default_ns: int) -> Iterator[tuple[int, fm.Log]]:
    """(wall time [ns], ``foxglove.Log``) of every line of every ``*.log`` in ``log_dir``
    (:func:`log_line`; ``default_ns`` for lines before the first stamped one)."""
    for f in sorted(pathlib.Path(log_dir).glob("*.log")):
        last = default_ns
        for raw in f.read_text(errors="replace").splitlines():
            if raw.strip():
                last, msg = log_line(raw, f.stem, last)
                yield last, msg


def foxglove_layout(scenario: Scenario) -> str:
    """A Foxglove layout (JSON, ``foxglove.layouts``) for the views: a top-down 3D panel in
    the frame ``world`` centred on the scenario's paths with every scene view on, beside
    Log panels for ``/viz/events`` and ``/viz/log``."""
    import foxglove.layouts as fl  # noqa: PLC0415

    pts = [path.pos(np.linspace(0.0, path.length, 100)) for path in scenario.paths.values()]
    pts += [np.asarray([r.pose[:2] for r in scenario.robots], dtype=float)]
    allp = np.concatenate(pts)
    centre = (allp.min(axis=0) + allp.max(axis=0)) / 2
    span = float(np.max(allp.max(axis=0) - allp.min(axis=0)))
    scene = {t: fl.BaseRendererSceneUpdateTopicSettings(visible=True) for t, c in TOPICS.items() if c is fm.SceneUpdate}
    topics: dict = {**scene, "/viz/robots": fl.BaseRendererPosesTopicSettings(visible=False)}
    three_d = fl.ThreeDeePanel(title=f"{scenario.id}", config=fl.ThreeDeeConfig(
        follow_tf=FRAME, fixed_frame=FRAME, follow_mode="follow-none", topics=topics,
        camera_state=fl.ThreeDeeCameraState(perspective=False, distance=1.6 * span + 1.0, phi=0.0, theta_offset=0.0,
                                             target=(float(centre[0]), float(centre[1]), 0.0))))
    logs = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=1, content=fl.LogPanel(title="events", config=fl.LogConfig(topic_to_render="/viz/events"))),
        fl.SplitItem(proportion=2, content=fl.LogPanel(title="process logs", config=fl.LogConfig(topic_to_render="/viz/log"))),
    ])
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=three_d), fl.SplitItem(proportion=1, content=logs)])).to_json()


class McapVizSink:
    """Logs Foxglove messages as protobuf, with the schema (a FileDescriptorSet) that
    ``foxglove-sdk`` ships for each type, on channels of a ``foxglove.Context`` whose MCAP
    writer is the run's log (``orchestrator/log/writer.py``)."""

    def __init__(self, context: foxglove.Context) -> None:
        self._ctx = context
        self._channels: dict[str, foxglove.Channel] = {}
        self.count = 0

    def _channel(self, topic: str, msg) -> foxglove.Channel:
        ch = self._channels.get(topic)
        if ch is None:
            schema = type(msg).get_schema()
            ch = foxglove.Channel(topic, message_encoding="protobuf", context=self._ctx,
                                  schema=foxglove.Schema(name=schema.name, encoding=schema.encoding, data=schema.data))
            self._channels[topic] = ch
        return ch

    def log(self, topic: str, msg, log_time_ns: int) -> None:
        """Log ``msg`` (caller holds the recorder's lock)."""
        self._channel(topic, msg).log(msg.encode(), log_time=log_time_ns)
        self.count += 1


class RecordedViews:
    """The Foxglove views written into a run's log as it is recorded: a tap on the log's
    recorder (``orchestrator.log.writer.Recorder.add_tap``), which knows nothing of views.
    Each record it is fed yields messages, written as protobuf channels of the same MCAP
    (:class:`McapVizSink`) and handed to ``live`` (``orchestrator/view/live.py``) as well."""

    def __init__(self, recorder, scenario: Scenario, live=None) -> None:
        self._recorder = recorder
        self._viz = VizBuilder(scenario, recorder.keys)
        self.skip = ("/cmd", "/estimate") + (() if scenario.sensors.enabled else ("/obs",))
        """Records the views never use are not decoded (observations only for range rays)."""
        self._live = live
        self._mcap: McapVizSink | None = None
        self._lock = threading.Lock()  # the builder keeps state across records
        self._static = self._viz.static()  # written with the first record, at its time
        recorder.add_tap(self)

    def feed(self, key: str, rec: Any, log_time_ns: int) -> None:
        with self._lock:
            if self._static:
                self._emit(self._static, log_time_ns)
                self._static = []
            self._emit(self._viz.feed(key, rec), log_time_ns)

    def _emit(self, msgs, now: int) -> None:
        """Write Foxglove messages into the log (under its writer's lock), then to the live server."""
        if not msgs:
            return
        with self._recorder.derived() as context:
            if context is None:  # the log is closed
                return
            if self._mcap is None:
                self._mcap = McapVizSink(context)
            for topic, msg in msgs:
                self._mcap.log(topic, msg, now)
        if self._live is not None:
            for topic, msg in msgs:
                self._live.log(topic, msg, now)

    def add_process_logs(self, log_dir: str | pathlib.Path) -> int:
        """Every line of the processes' logs (``log_dir/*.log``) as ``foxglove.Log`` on
        ``/viz/log``; returns the number of lines."""
        if not pathlib.Path(log_dir).is_dir():
            return 0
        n = 0
        for t, msg in process_log_messages(log_dir, time.time_ns()):
            self._emit([("/viz/log", msg)], t)
            n += 1
        return n


def views_tap(scenario: Scenario, live=None) -> Callable[[Any], RecordedViews]:
    """What ``orchestrator.log.writer.write_records(taps=...)`` calls to add the views to a log."""
    return lambda recorder: RecordedViews(recorder, scenario, live)
