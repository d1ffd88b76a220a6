"""Foxglove views: every /viz message in a run log decodes with the schema Foxglove
publishes for its type (the protobuf FileDescriptorSet foxglove-sdk ships, stored in the
log) and carries what the run shows: robots, plans, targets, rays, links, faults, logs."""

from __future__ import annotations

import collections
import datetime

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from mcap.reader import make_reader

from copath.scenario import load_scenario
from orchestrator.inprocess import run_scenario
from orchestrator.mcaplog import Recorder, read_log, write_records
from orchestrator.viz import TOPICS, process_log_messages
from tests.conftest import config

PARTITION = {"links": [["r1", "r2"]], "start_s": 0.5, "end_s": 1.0}


def _decode_viz(path):
    """{topic: [decoded message as a dict]} for every protobuf channel of ``path``."""
    classes, out = {}, collections.defaultdict(list)
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
    write_records(path, res.records, s, "viz")
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
    cut = [m for m in viz["/viz/links"] if len(m["entities"][0]["lines"]) == 2]
    stamps = [_secs(m["entities"][0]["timestamp"]) for m in cut]
    assert cut and all(0.5 - 1e-9 <= t < 1.0 for t in stamps)
    assert len(cut[0]["entities"][0]["lines"][1]["points"]) == 2  # one segment: r1-r2
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

    rec = Recorder(path, Keys("viz"), {}, s)
    for t, key, r in res.records[:50]:
        rec.write(key, r.pack(), log_time_ns=t)
    assert rec.add_process_logs(logs) == 4
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
    rec = Recorder(path, keys, {}, s)
    plan = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.05, 0.1]]
    rec.write(keys.telemetry("r1"), Telemetry(0, 0.0, {"ref": [0.0, 0.0, 0.0], "plan": plan}).pack(), 1)
    rec.write(keys.truth, Truth(0, 0.0, ["r1"], [[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], [False], [0.0]).pack(), 2)
    rec.finish()
    ent = _decode_viz(path)["/viz/plans"][-1]["entities"][0]
    pts = [(p.get("x", 0.0), p.get("y", 0.0)) for p in ent["lines"][0]["points"]]
    assert ent["id"] == "plan/r1" and pts == [(0.0, 0.0), (0.1, 0.0), (0.2, 0.05)]


def test_log_tail_sends_complete_lines_once(tmp_path):
    from orchestrator.live import LogTail

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
