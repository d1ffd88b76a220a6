"""Foxglove views: every /viz message in a run log decodes with the schema Foxglove
publishes for its type (the protobuf FileDescriptorSet foxglove-sdk ships, stored in the
log), validates in its JSON form against Foxglove's published JSON schema
(tests/data/foxglove_jsonschema), and carries what the run shows: robots, plans, targets,
rays, links, faults, logs."""

from __future__ import annotations

import base64
import collections
import datetime
import json
import pathlib

import jsonschema
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from mcap.reader import make_reader

from copath.scenario import load_scenario
from orchestrator.run.inprocess import run_scenario
from orchestrator.log.mcap import read_log
from orchestrator.log.writer import Recorder, write_records
from orchestrator.view.foxglove import TOPICS, RecordedViews, process_log_messages, views_tap
from tests.conftest import config

JSON_SCHEMAS = pathlib.Path(__file__).resolve().parents[1] / "data" / "foxglove_jsonschema"
_WKT_TIME = ("google.protobuf.Timestamp", "google.protobuf.Duration")
PARTITION = {"links": [["r1", "r2"]], "start_s": 0.5, "end_s": 1.0}


def _foxglove_json(msg) -> dict:
    """A decoded protobuf message in Foxglove's JSON form: every field, times as
    {sec, nsec}, enums as integers, bytes as base64."""
    out = {}
    for f in msg.DESCRIPTOR.fields:
        v = getattr(msg, f.name)
        if f.message_type is not None and f.message_type.full_name in _WKT_TIME:
            conv = lambda x: {"sec": x.seconds, "nsec": x.nanos}  # noqa: E731
        elif f.message_type is not None:
            conv = _foxglove_json
        elif isinstance(v, bytes):
            conv = lambda x: base64.b64encode(x).decode()  # noqa: E731
        else:
            conv = lambda x: x  # noqa: E731
        repeated = f.is_repeated if hasattr(f, "is_repeated") else f.label == f.LABEL_REPEATED
        out[f.name] = [conv(x) for x in v] if repeated else conv(v)
    return out


def _declared(value, schema, where="$"):
    """Every key of ``value`` is a property of ``schema`` (the schemas allow extra keys)."""
    if isinstance(value, dict):
        props = schema.get("properties", {})
        for k, v in value.items():
            assert k in props, f"{where}.{k} is not in {schema.get('title')}"
            _declared(v, props[k], f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            _declared(v, schema.get("items", {}), f"{where}[{i}]")


def _json_schema(name: str) -> dict:
    return json.loads((JSON_SCHEMAS / f"{name.removeprefix('foxglove.')}.json").read_text())


def _decode_viz(path):
    """{topic: [decoded message as a dict]} for every protobuf channel of ``path``; each
    message is also validated against Foxglove's JSON schema of its type."""
    classes, out = {}, collections.defaultdict(list)
    validators = {}
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            if channel.message_encoding != "protobuf":
                continue
            assert schema.encoding == "protobuf" and schema.name.startswith("foxglove."), schema.name
            assert schema.name == TOPICS[channel.topic].get_schema().name, channel.topic
            if schema.name not in classes:
                pool = descriptor_pool.DescriptorPool()
                for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                    pool.Add(f)
                classes[schema.name] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            msg = classes[schema.name].FromString(message.data)  # raises on bytes that do not fit the schema
            assert msg.SerializeToString() == message.data or msg.ByteSize() == len(message.data)
            if schema.name not in validators:
                js = _json_schema(schema.name)
                validators[schema.name] = (jsonschema.Draft202012Validator(js), js)
            validator, js = validators[schema.name]
            as_json = _foxglove_json(msg)
            validator.validate(as_json)
            _declared(as_json, js)
            out[channel.topic].append(json_format.MessageToDict(msg, preserving_proto_field_name=True))
    return out


def _secs(stamp: str) -> float:
    """Seconds of a decoded google.protobuf.Timestamp (RFC 3339; views carry sim time)."""
    return datetime.datetime.fromisoformat(stamp).timestamp()


def _log(tmp_path_factory, prefix, duration, name, **overrides):
    s = load_scenario(config(prefix))
    if overrides:
        s = s.with_overrides(**overrides)
    res = run_scenario(s, duration_s=duration, run_id="viz")
    path = tmp_path_factory.mktemp(name) / "run.mcap"
    write_records(path, res.records, s, "viz", taps=[views_tap(s)])
    return s, res, path


@pytest.fixture(scope="module")
def dmpc_faults(tmp_path_factory):
    return _log(tmp_path_factory, "e5.2-", 1.5, "dmpc", network={"loss": 0.2, "partitions": [PARTITION]})


@pytest.fixture(scope="module")
def leader(tmp_path_factory):
    return _log(tmp_path_factory, "e5.1-", 1.0, "leader")


@pytest.fixture(scope="module")
def obstacles(tmp_path_factory):
    return _log(tmp_path_factory, "e4.6-", 0.5, "obst")


def test_dmpc_views_decode_and_show_plans_links_and_the_partition(dmpc_faults):
    s, res, path = dmpc_faults
    viz = _decode_viz(path)
    ticks = sum(1 for _, _, r in res.records if r.TYPE == "truth")
    assert {"/viz/scene", "/viz/robots", "/viz/plans", "/viz/formation", "/viz/links", "/viz/events"} <= set(viz)
    assert len(viz["/viz/robots"]) == ticks and all(len(m["poses"]) == 3 for m in viz["/viz/robots"])
    paths = viz["/viz/scene"][0]["entities"][0]
    assert paths["id"] == "paths" and len(paths["lines"]) == len(s.paths)
    world = viz["/viz/scene"][-1]["entities"][0]
    assert len(world["cylinders"]) == 3 and len(world["arrows"]) == 3
    # every robot shows the assumed trajectory it broadcast (Algorithm 5.1, step 2) once it sent one
    last = {e["id"]: e for e in viz["/viz/plans"][-1]["entities"]}
    assert set(last) == {"plan/r1", "plan/r2", "plan/r3"}
    assert all(len(e["lines"]) == 1 and len(e["lines"][0]["points"]) > 2 for e in last.values())
    assert all(len(e["spheres"]) == 1 for e in last.values())  # the reference point
    # the partition cuts r1-r2 for t in [0.5, 1.0): a red line while it lasts, none after
    def lines(m, kind):  # green: up, orange: latest message lost, red: cut by a partition
        rgb = {"up": (0.1, 0.7), "lost": (1.0, 0.55), "cut": (0.9, 0.1)}[kind]
        return [ln for ln in m["entities"][0]["lines"]
                if (round(ln["color"].get("r", 0.0), 2), round(ln["color"].get("g", 0.0), 2)) == rgb]

    cut = [m for m in viz["/viz/links"] if lines(m, "cut")]
    stamps = [_secs(m["entities"][0]["timestamp"]) for m in cut]
    assert cut and all(0.5 - 1e-9 <= t < 1.0 for t in stamps)
    assert all(len(lines(m, "cut")[0]["points"]) == 2 for m in cut)  # one segment: r1-r2
    # with 20 % loss some frames show links whose latest message was lost
    lost = [m for m in viz["/viz/links"] if lines(m, "lost")]
    assert lost and all(len(lines(m, "lost")[0]["points"]) % 2 == 0 for m in lost)
    messages = [m["message"] for m in viz["/viz/events"]]
    assert any("partition 0 cuts r1-r2" in m for m in messages)
    assert any("partition 0 over" in m for m in messages)
    assert any(m.startswith("end of run") for m in messages)


def test_leader_plan_becomes_a_horizon_on_the_leaders_path(leader):
    s, _, path = leader
    viz = _decode_viz(path)
    last = {e["id"]: e for e in viz["/viz/plans"][-1]["entities"]}
    ln = s.robots[0].name
    assert s.robots[0].controller.startswith("leader")
    pts = last[f"plan/{ln}"]["lines"][0]["points"]
    assert len(pts) > 2
    # followers hold formation targets: a line from each robot to its target
    form = viz["/viz/formation"][-1]["entities"][0]
    assert form["lines"] and len(form["spheres"]) >= 1


def test_range_rays_and_moving_obstacles(obstacles):
    s, _, path = obstacles
    viz = _decode_viz(path)
    rays = viz["/viz/ranges"][-1]["entities"][0]["lines"][0]["points"]
    assert len(rays) == 2 * s.sensors.count  # one segment per sensor
    first = viz["/viz/scene"][1]["entities"][0]["lines"]
    last = viz["/viz/scene"][-1]["entities"][0]["lines"]
    assert len(first) == len(s.obstacles) >= 1
    assert first[0]["points"] != last[0]["points"]  # they move
    assert "/viz/links" not in viz  # a single robot has no links


def test_process_logs_become_foxglove_logs(tmp_path, dmpc_faults):
    s, res, _ = dmpc_faults
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "r1.log").write_text("2026-01-02 03:04:05,678 r1 WARNING late peer message\n"
                                 "Traceback (most recent call last):\n\n"
                                 "2026-01-02 03:04:06,000 r1 INFO done\n")
    (logs / "sim.log").write_text("solver says hello\n")
    got = list(process_log_messages(logs, default_ns=123))
    assert len(got) == 4
    t0, t1, t2, t3 = (t for t, _ in got)
    assert t1 == t0 and t2 - t0 == 322_000_000 and t3 == 123  # a traceback keeps the time of its line
    path = tmp_path / "run.mcap"
    from copath.wire.keys import Keys

    rec = Recorder(path, Keys("viz"), {})
    views = RecordedViews(rec, s)
    for t, key, r in res.records[:50]:
        rec.write(key, r.pack(), log_time_ns=t)
    assert views.add_process_logs(logs) == 4
    rec.finish()
    viz = _decode_viz(path)
    logged = [(m["name"], m.get("level", "UNKNOWN"), m["message"]) for m in viz["/viz/log"]]
    assert sorted(logged) == sorted([("r1", "WARNING", "late peer message"),
                                     ("r1", "UNKNOWN", "Traceback (most recent call last):"),
                                     ("r1", "INFO", "done"), ("sim", "UNKNOWN", "solver says hello")])
    assert len(read_log(path).records) == 50  # the views are not run messages


def test_a_plan_in_telemetry_is_drawn_as_the_robots_horizon(tmp_path):
    from copath.wire.keys import Keys
    from copath.wire.messages import Telemetry, Truth

    s = load_scenario(config("e4.2-"))
    keys = Keys("plan")
    path = tmp_path / "run.mcap"
    rec = Recorder(path, keys, {})
    RecordedViews(rec, s)
    plan = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.05, 0.1]]
    rec.write(keys.telemetry("r1"), Telemetry(0, 0.0, {"ref": [0.0, 0.0, 0.0], "plan": plan}).pack(), 1)
    rec.write(keys.truth, Truth(0, 0.0, ["r1"], [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], [False], [0.0]).pack(), 2)
    rec.finish()
    ent = _decode_viz(path)["/viz/plans"][-1]["entities"][0]
    pts = [(p.get("x", 0.0), p.get("y", 0.0)) for p in ent["lines"][0]["points"]]
    assert ent["id"] == "plan/r1" and pts == [(0.0, 0.0), (0.1, 0.0), (0.2, 0.05)]


def test_log_tail_sends_complete_lines_once(tmp_path):
    from orchestrator.view.live import LogTail

    got = []

    class Sink:
        def log(self, topic, msg, t):
            got.append((topic, t))

    f = tmp_path / "r1.log"
    f.write_text("2026-01-02 03:04:05,678 r1 INFO one\npartial")
    tail = LogTail(tmp_path, Sink())
    assert tail.poll() == 1 and got[0][0] == "/viz/log"
    with f.open("a") as fh:
        fh.write(" line\n2026-01-02 03:04:06,000 r1 WARNING two\n")
    assert tail.poll() == 2 and tail.poll() == 0
    assert got[1][1] == got[0][1] and got[2][1] - got[0][1] == 322_000_000  # the unstamped line keeps the time


def test_the_json_schemas_reject_what_foxglove_would_not_read():
    from foxglove import messages as fm

    from copath.wire.keys import Keys
    from orchestrator.view.foxglove import VizBuilder

    (_, msg), = VizBuilder(load_scenario(config("e5.5-")), Keys("x")).static()
    schema = type(msg).get_schema()
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    decoded = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString(msg.encode())
    good = _foxglove_json(decoded)
    js = _json_schema(schema.name)
    jsonschema.Draft202012Validator(js).validate(good)
    _declared(good, js)
    bad = json.loads(json.dumps(good))
    bad["entities"][0]["timestamp"]["nsec"] = 2_000_000_000
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(js).validate(bad)
    del bad["entities"][0]["lifetime"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(js).validate(bad)
    with pytest.raises(AssertionError, match="not in foxglove.SceneEntity"):
        _declared({"deletions": [], "entities": [{"colour": 1}]}, js)
    assert fm.SceneUpdate.get_schema().name == schema.name


def test_the_views_are_added_beside_the_run_records_which_they_leave_unchanged(tmp_path):
    """The recorder knows nothing of views: without a tap the log holds the run's channels
    only; with the Foxglove views added (what ``copath run`` composes) it holds the same run
    messages, byte for byte and at the same times, and the ``/viz`` channels beside them."""
    s = load_scenario(config("e5.5-column-box"))  # range sensors on: the ray view too
    res = run_scenario(s, duration_s=2.0, run_id="taps")
    plain = write_records(tmp_path / "plain.mcap", res.records, s, "taps", origin_ns=0)
    viewed = write_records(tmp_path / "viewed.mcap", res.records, s, "taps", origin_ns=0, taps=[views_tap(s)])

    def messages(path):
        with open(path, "rb") as fh:
            return [(c.topic, c.message_encoding, m.log_time, m.data)
                    for _, c, m in make_reader(fh).iter_messages(log_time_order=True)]

    run_only = messages(plain)
    both = messages(viewed)
    assert run_only and all(enc == "msgpack" for _, enc, _, _ in run_only)
    assert [m for m in both if m[1] == "msgpack"] == run_only
    views = {topic for topic, enc, _, _ in both if enc == "protobuf"}
    assert views == {"/viz/scene", "/viz/robots", "/viz/plans", "/viz/formation", "/viz/ranges", "/viz/links",
                     "/viz/events"}  # the end of the run
    assert read_log(plain).metadata == read_log(viewed).metadata
