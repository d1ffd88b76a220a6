"""Foxglove visualisation channels derived from the simulator's truth.

The recorder adds two JSON channels to ``run.mcap`` beside the raw msgpack messages so
a run opens directly in Foxglove: ``/viz/scene`` (``foxglove.SceneUpdate``: the
scenario's paths as line strips, obstacles as closed polygons, robots as discs with a
heading arrow) and ``/viz/robots`` (``foxglove.PosesInFrame``). Only the fields used
are declared in the schemas below (field names follow Foxglove's published schemas).
They are derived data, outside the run's key space, and not counted as messages.
"""

from __future__ import annotations

import json
import math

import numpy as np

from copath.scenario import Scenario
from copath.wire.messages import Truth

__all__ = ["SCHEMAS", "scene_update", "poses_in_frame", "static_scene"]

FRAME = "world"

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}, "required": list("xyz")}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}, "required": list("xyzw")}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}, "required": ["position", "orientation"]}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in ("r", "g", "b", "a")}}
_LINE = {"type": "object", "properties": {"type": {"type": "integer"}, "pose": _POSE, "thickness": {"type": "number"},
                                          "scale_invariant": {"type": "boolean"},
                                          "points": {"type": "array", "items": _VEC3}, "color": _COLOR}}
_CYL = {"type": "object", "properties": {"pose": _POSE, "size": _VEC3, "bottom_scale": {"type": "number"},
                                         "top_scale": {"type": "number"}, "color": _COLOR}}
_ARROW = {"type": "object", "properties": {"pose": _POSE, "shaft_length": {"type": "number"},
                                           "shaft_diameter": {"type": "number"}, "head_length": {"type": "number"},
                                           "head_diameter": {"type": "number"}, "color": _COLOR}}
_ENTITY = {"type": "object", "properties": {
    "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"}, "lifetime": _TIME,
    "frame_locked": {"type": "boolean"}, "lines": {"type": "array", "items": _LINE},
    "cylinders": {"type": "array", "items": _CYL}, "arrows": {"type": "array", "items": _ARROW}}}

SCHEMAS = {
    "foxglove.SceneUpdate": {"title": "foxglove.SceneUpdate", "type": "object", "properties": {
        "deletions": {"type": "array", "items": {"type": "object"}},
        "entities": {"type": "array", "items": _ENTITY}}},
    "foxglove.PosesInFrame": {"title": "foxglove.PosesInFrame", "type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "poses": {"type": "array", "items": _POSE}}},
}
TOPICS = {"/viz/scene": "foxglove.SceneUpdate", "/viz/robots": "foxglove.PosesInFrame"}

_PALETTE = [(0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
            (0.58, 0.4, 0.74), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5)]


def _time(t: float) -> dict:
    sec = int(math.floor(t))
    return {"sec": sec, "nsec": int(round((t - sec) * 1e9)) % 1_000_000_000}


def _pose(x: float, y: float, th: float = 0.0) -> dict:
    return {"position": {"x": float(x), "y": float(y), "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(th / 2), "w": math.cos(th / 2)}}


def _color(i: int, a: float = 1.0) -> dict:
    r, g, b = _PALETTE[i % len(_PALETTE)]
    return {"r": r, "g": g, "b": b, "a": a}


def static_scene(scenario: Scenario) -> bytes:
    """The scenario's paths as line strips (lifetime 0: kept until replaced)."""
    lines = []
    for i, (name, path) in enumerate(scenario.paths.items()):
        s = np.linspace(0.0, path.length, max(50, int(path.length / 0.02)))
        p = path.pos(s)
        lines.append({"type": 1 if path.closed else 0, "pose": _pose(0, 0), "thickness": 2.0, "scale_invariant": True,
                      "points": [{"x": float(a), "y": float(b), "z": 0.0} for a, b in p],
                      "color": {"r": 0.6, "g": 0.6, "b": 0.6, "a": 0.8}})
    msg = {"deletions": [], "entities": [{"timestamp": _time(0.0), "frame_id": FRAME, "id": "paths",
                                          "lifetime": _time(0.0), "frame_locked": False, "lines": lines,
                                          "cylinders": [], "arrows": []}]}
    return json.dumps(msg).encode()


def scene_update(truth: Truth, radii: dict[str, float]) -> bytes:
    cyl, arrows, lines = [], [], []
    for i, (n, p) in enumerate(zip(truth.names, truth.poses)):
        r = radii.get(n, 0.1)
        cyl.append({"pose": _pose(p[0], p[1], p[2]), "size": {"x": 2 * r, "y": 2 * r, "z": 0.05},
                    "bottom_scale": 1.0, "top_scale": 1.0, "color": _color(i, 0.8)})
        arrows.append({"pose": _pose(p[0], p[1], p[2]), "shaft_length": 1.5 * r, "shaft_diameter": 0.3 * r,
                       "head_length": 0.6 * r, "head_diameter": 0.7 * r, "color": _color(i)})
    for poly in truth.obstacles or []:
        lines.append({"type": 1, "pose": _pose(0, 0), "thickness": 3.0, "scale_invariant": True,
                      "points": [{"x": float(a), "y": float(b), "z": 0.0} for a, b in poly],
                      "color": {"r": 0.1, "g": 0.1, "b": 0.1, "a": 1.0}})
    msg = {"deletions": [], "entities": [{"timestamp": _time(truth.t), "frame_id": FRAME, "id": "world",
                                          "lifetime": _time(0.0), "frame_locked": False, "lines": lines,
                                          "cylinders": cyl, "arrows": arrows}]}
    return json.dumps(msg).encode()


def poses_in_frame(truth: Truth) -> bytes:
    return json.dumps({"timestamp": _time(truth.t), "frame_id": FRAME,
                       "poses": [_pose(p[0], p[1], p[2]) for p in truth.poses]}).encode()
