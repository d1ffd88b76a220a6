"""Live Foxglove views: a WebSocket client sees the channels advertised and messages flow,
while a fleet runs (real processes over Zenoh) and while a recorded log replays."""

from __future__ import annotations

import base64
import json
import struct
import threading
import time

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import connect

from copath.scenario import load_scenario
from copath.wire.session import free_port
from orchestrator.run.fleet import RunOptions, run_fleet
from orchestrator.run.inprocess import run_scenario
from orchestrator.view.live import LiveViz, serve_log
from orchestrator.log.writer import write_records
from orchestrator.view.foxglove import TOPICS
from tests.conftest import config

pytestmark = [pytest.mark.fleet, pytest.mark.timeout(180)]

SUBPROTOCOL = "foxglove.sdk.v1"


def _connect(port: int, deadline_s: float = 20.0):
    end = time.monotonic() + deadline_s
    while True:
        try:
            return connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=5)
        except OSError:
            if time.monotonic() > end:
                raise
            time.sleep(0.1)


def _watch(port: int, want: int, timeout_s: float) -> tuple[dict, dict]:
    """Connect, subscribe to every advertised channel, and collect messages until
    ``want`` arrived: ({topic: channel}, {topic: [payload bytes]})."""
    channels, got = {}, {}
    with _connect(port) as ws:
        info = json.loads(ws.recv(timeout=10))
        assert info["op"] == "serverInfo"
        end = time.monotonic() + timeout_s
        subs: dict[int, str] = {}
        while time.monotonic() < end and sum(map(len, got.values())) < want:
            try:
                frame = ws.recv(timeout=1)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        channels[ch["topic"]] = ch
                        sid = len(subs) + 1
                        subs[sid] = ch["topic"]
                        new.append({"id": sid, "channelId": ch["id"]})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            else:
                assert frame[0] == 0x01  # message data: opcode, subscription id, log time, payload
                sid, _log_time = struct.unpack_from("<IQ", frame, 1)
                got.setdefault(subs[sid], []).append(frame[13:])
    return channels, got


def _decode(channel: dict, payload: bytes):
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"])).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"])).FromString(payload)


def test_live_views_of_a_running_fleet(tmp_path):
    s = load_scenario(config("e5.5-")).with_overrides(run={"duration_s": 4.0, "settle_s": 0.0})
    port = free_port()
    outcome = {}

    def run():
        outcome["o"] = run_fleet(s, RunOptions(out_dir=tmp_path, run_id="live-test", progress=False, live_port=port,
                                                    wall_timeout_s=90.0))

    th = threading.Thread(target=run, daemon=True)
    th.start()
    try:
        channels, got = _watch(port, want=30, timeout_s=120)
    finally:
        th.join(timeout=150)
    assert not th.is_alive() and outcome["o"].ok, outcome.get("o")
    assert set(TOPICS) <= set(channels)
    assert all(channels[t]["schemaName"] == TOPICS[t].get_schema().name for t in TOPICS)
    assert got.get("/viz/robots"), got.keys()
    poses = _decode(channels["/viz/robots"], got["/viz/robots"][-1])
    assert len(poses.poses) == len(s.robots)
    assert "/viz/scene" in got and "/viz/links" in got


def test_live_views_of_a_replayed_log(tmp_path):
    s = load_scenario(config("e5.2-"))
    res = run_scenario(s, duration_s=1.0, run_id="replay-live")
    log = write_records(tmp_path / "run.mcap", res.records, s, "replay-live")
    live = LiveViz(free_port())
    live.advertise(TOPICS)
    stop = threading.Event()
    sent = {}

    def feed():
        time.sleep(1.0)  # let the client subscribe first
        sent["n"] = serve_log(log, live, speed=1.0, stop=stop)

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    try:
        channels, got = _watch(live.port, want=40, timeout_s=60)
    finally:
        stop.set()
        th.join(timeout=30)
        live.close()
    assert set(TOPICS) <= set(channels)
    plans = _decode(channels["/viz/plans"], got["/viz/plans"][-1])
    assert {e.id for e in plans.entities} == {"plan/r1", "plan/r2", "plan/r3"}
    assert sum(map(len, got.values())) >= 40
