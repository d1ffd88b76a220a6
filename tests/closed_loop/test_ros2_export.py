"""``copath export --ros2``: a run as a ROS 2 bag, read back by two independent readers."""

from __future__ import annotations

import collections

import pytest

from orchestrator import api
from orchestrator.cli import main as copath

pytest.importorskip("mcap_ros2", reason="copath export --ros2 needs the ros2 extra (mcap-ros2-support)")
pytest.importorskip("rosbags", reason="the bag is read back with rosbags (the ros2 extra)")


def test_dmpc_run_exports_as_a_ros2_bag_both_readers_agree(tmp_path, capsys):
    """E5.2 (DMPC, Algorithm 5.1): odometry and tf per tick, the broadcast horizons as
    nav_msgs/Path, the reference paths once; cdr encoding, ros2msg schemas."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    run = api.run("e5.2-dmpc-ellipse-triangle", {"run.duration_s": 2.0, "run.settle_s": 1.0}, inprocess=True,
                  out_dir=tmp_path / "run")
    names = list(run.scenario.robot_names)
    ticks = len(run.poses()[names[0]])
    out = tmp_path / "bag.mcap"
    assert copath(["export", "--ros2", str(tmp_path / "run" / "run.mcap"), str(out)]) == 0
    assert "msg/s" in capsys.readouterr().out

    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}

    store = get_typestore(Stores.ROS2_KILTED)
    seen: collections.Counter = collections.Counter()
    last = {}
    with Reader(out) as bag:  # rosbags: an independent CDR reader
        types = {c.topic: c.msgtype for c in bag.connections}
        for conn, _, raw in bag.messages():
            last[conn.topic] = store.deserialize_cdr(raw, conn.msgtype)
            seen[conn.topic] += 1
    assert types["/tf"] == "tf2_msgs/msg/TFMessage"
    for n in names:
        assert types[f"/{n}/odom"] == "nav_msgs/msg/Odometry" and seen[f"/{n}/odom"] == ticks
        assert types[f"/{n}/plan"] == "nav_msgs/msg/Path" and 1 <= seen[f"/{n}/plan"] <= ticks
        assert len(last[f"/{n}/plan"].poses) > 1
        x, y = run.poses()[n][-1, 1:3]
        assert last[f"/{n}/odom"].pose.pose.position.x == pytest.approx(x)
        assert last[f"/{n}/odom"].pose.pose.position.y == pytest.approx(y)
        assert last[f"/{n}/odom"].child_frame_id == f"{n}/base_link"
    assert seen["/tf"] == ticks and len(last["/tf"].transforms) == len(names)
    assert {t for t in types if t.startswith("/paths/")} == {f"/paths/{p}" for p in run.scenario.paths}
    # mcap-ros2-support decodes the same messages
    with open(out, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        again = collections.Counter(ch.topic for _, ch, _, msg in reader.iter_decoded_messages() if msg is not None)
    assert again == seen


def test_export_of_a_missing_log_is_one_line(tmp_path, capsys):
    assert copath(["export", "--ros2", str(tmp_path / "none.mcap"), str(tmp_path / "out.mcap")]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
