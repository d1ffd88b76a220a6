"""What tests read from a run's records (a log's, or an in-process run's ``records``)."""

from __future__ import annotations

from copath.wire.messages import Stats


def closing_counters(records, key: str | None = None) -> dict:
    """Each process's closing counters (its ``stats`` record) by process name, the simulator's
    left out; with ``key``, that one counter of each."""
    out = {r.proc: r.counters for _, _, r in records if isinstance(r, Stats) and r.proc != "sim"}
    return out if key is None else {p: c[key] for p, c in out.items()}
