"""The recorder's accounts from the link's sequence numbers (docs/reference/faults.md, "Accounts that
survive a kill"): gaps are found, a late record closes its gap, a killed process is counted
to its last record, a restarted one is a new incarnation."""

from __future__ import annotations

import json

from copath.wire.keys import Keys
from copath.wire.messages import Command, Stats
from copath.wire.session import read_seq_attachment, seq_attachment
from orchestrator.log.mcap import read_metadata
from orchestrator.log.writer import Recorder


def test_the_attachment_round_trips_and_foreign_ones_are_ignored():
    assert read_seq_attachment(seq_attachment(0xABCDEF, 42, "r2")) == (0xABCDEF, 42, "r2")
    assert read_seq_attachment(None) is None and read_seq_attachment(b"short") is None


def test_gaps_late_records_kills_and_restarts_are_accounted(tmp_path):
    keys = Keys("acct")
    rec = Recorder(tmp_path / "run.mcap", keys, {"copath": {"run_id": "acct"}})
    cmd = Command(0, 0.0, [0.0, 0.0]).pack()

    def put(inc, seq, sender="r1", data=cmd, key=None):
        rec.write(key or keys.cmd(sender), data, attachment=seq_attachment(inc, seq, sender))

    for s in (1, 2, 4, 3, 5, 7):  # 3 late (its gap closes), 6 never arrives
        put(1, s)
    put(1, 8, data=Stats("r1", 7, {}).pack(), key=keys.stats("r1"))  # its closing account: 7 published
    for s in (1, 2, 3):  # r2 killed after its 3rd record: no closing account
        put(9, s, "r2")
    for s in (1, 2):  # r2 restarted: a new incarnation
        put(10, s, "r2")
    rec.write(keys.event("orchestrator"), cmd)  # no attachment: not in any account
    accts = {(a["sender"], a["incarnation"]): a for a in rec.accounts.values()}
    r1 = accts[("r1", f"{1:012x}")]
    assert r1["received"] == 7 and r1["missing"] == 1 and r1["closed"] == 7 and r1["last"] == 8
    killed = accts[("r2", f"{9:012x}")]
    assert killed["closed"] is None and killed["last"] == 3 and killed["missing"] == 0
    assert accts[("r2", f"{10:012x}")]["received"] == 2
    rec.finish()
    meta = {k: json.loads(v) for k, v in read_metadata(tmp_path / "run.mcap")["accounts"].items()}
    assert sorted(a["sender"] for a in meta.values()) == ["r1", "r2", "r2"]
    assert sum(a["missing"] for a in meta.values()) == 1


def test_a_restart_is_timed_to_its_first_command_not_to_when_someone_looks(tmp_path):
    # the supervisor's rejoin bound (docs/reference/faults.md) reads first_cmd_ns: the receive
    # time of the first command after expect_commands, kept however many commands follow
    keys = Keys("rejoin")
    rec = Recorder(tmp_path / "run.mcap", keys, {"copath": {"run_id": "rejoin"}})
    cmd = Command(0, 0.0, [0.0, 0.0]).pack()
    rec.write(keys.cmd("r2"), cmd, log_time_ns=1_000)
    assert "r2" not in rec.first_cmd_ns  # nothing expected: not noted
    rec.expect_commands("r2")
    assert rec.first_cmd_ns["r2"] == 0
    rec.write(keys.cmd("r1"), cmd, log_time_ns=2_000)  # another robot's command does not count
    assert rec.first_cmd_ns["r2"] == 0
    for t in (3_000, 4_000, 5_000):
        rec.write(keys.cmd("r2"), cmd, log_time_ns=t)
    assert rec.first_cmd_ns["r2"] == 3_000 and "r1" not in rec.first_cmd_ns
    rec.finish()


def test_a_command_of_the_killed_process_still_in_flight_is_not_the_restart(tmp_path):
    # the killed incarnation's last commands can reach the recorder after the restart began:
    # they are not the new process commanding again (its attachment says which process sent it)
    keys = Keys("inflight")
    rec = Recorder(tmp_path / "run.mcap", keys, {"copath": {"run_id": "inflight"}})
    cmd = Command(0, 0.0, [0.0, 0.0]).pack()
    rec.write(keys.cmd("r2"), cmd, log_time_ns=1_000, attachment=seq_attachment(7, 1, "r2"))
    rec.expect_commands("r2")
    rec.write(keys.cmd("r2"), cmd, log_time_ns=2_000, attachment=seq_attachment(7, 2, "r2"))  # old, late
    assert rec.first_cmd_ns["r2"] == 0
    rec.write(keys.cmd("r2"), cmd, log_time_ns=3_000, attachment=seq_attachment(8, 1, "r2"))  # the new one
    assert rec.first_cmd_ns["r2"] == 3_000
    rec.finish()
