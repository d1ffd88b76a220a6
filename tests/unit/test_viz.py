"""Foxglove channels: messages carry exactly the fields their schemas declare."""

import json

from copath.scenario import load_scenario
from copath.wire.messages import Truth
from orchestrator.viz import SCHEMAS, poses_in_frame, scene_update, static_scene
from tests.conftest import config


def _conforms(value, schema, path="$"):
    t = schema.get("type")
    if t == "object":
        assert isinstance(value, dict), path
        for k, v in value.items():
            assert k in schema["properties"], f"{path}.{k} is not in the schema"
            _conforms(v, schema["properties"][k], f"{path}.{k}")
        for k in schema.get("required", []):
            assert k in value, f"{path}.{k} is required"
    elif t == "array":
        assert isinstance(value, list), path
        for i, v in enumerate(value):
            _conforms(v, schema["items"], f"{path}[{i}]")
    elif t == "number":
        assert isinstance(value, (int, float)) and not isinstance(value, bool), path
    elif t == "integer":
        assert isinstance(value, int), path


def test_scene_and_poses_conform_to_their_schemas():
    s = load_scenario(config("e4.6-"))
    truth = Truth(3, 0.15, ["r1"], [[1.0, 0.5, 0.3]], [[0.1, 0.0]], [False], [0.1], [0.4],
                  [[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]])
    scene = json.loads(scene_update(truth, {"r1": 0.06}))
    _conforms(scene, SCHEMAS["foxglove.SceneUpdate"])
    ent = scene["entities"][0]
    assert len(ent["cylinders"]) == 1 and len(ent["lines"]) == 1 and ent["timestamp"] == {"sec": 0, "nsec": 150000000}
    poses = json.loads(poses_in_frame(truth))
    _conforms(poses, SCHEMAS["foxglove.PosesInFrame"])
    q = poses["poses"][0]["orientation"]
    assert abs(q["z"] ** 2 + q["w"] ** 2 - 1) < 1e-12
    paths = json.loads(static_scene(s))
    _conforms(paths, SCHEMAS["foxglove.SceneUpdate"])
    assert len(paths["entities"][0]["lines"]) == len(s.paths)
