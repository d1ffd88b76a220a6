"""The chaos soak's re-coordination grades (docs/reference/faults.md, "Chaos soak"): the first
instant below the tolerance after a fault's end, and the first from which it stays below for
``HOLD_S`` (docs/journal/faults.md, "First instant or for good")."""

from __future__ import annotations

import numpy as np

from orchestrator.studies.bench.chaos import COORD_TOL_M, HOLD_S, held_below

T = np.arange(0.0, 40.0, 0.1)


def test_an_error_that_builds_up_after_the_fault_is_not_hidden_by_a_first_instant_below():
    c = np.full(len(T), 0.01)
    c[(T > 12.0) & (T < 18.0)] = 0.5  # below at the fault's end (10 s), over from 12 to 18 s
    assert held_below(T, c, 10.0) == 8.0
    assert held_below(T, c, 20.0) == 0.0


def test_below_for_good_needs_hold_s_or_the_run_s_end():
    c = np.full(len(T), 0.5)
    c[(T > 20.0) & (T < 20.0 + HOLD_S - 1.0)] = COORD_TOL_M / 2  # a dip shorter than HOLD_S
    c[T > 36.0] = 0.0  # below from 36.1 s to the end (3.9 s): the run ends first
    assert abs(held_below(T, c, 10.0) - 26.1) < 1e-9
    assert held_below(T, np.full(len(T), 0.5), 5.0) is None


def test_no_live_pair_counts_as_below():
    c = np.full(len(T), np.nan)
    assert held_below(T, c, 3.0) == 0.0


def test_a_stretch_below_that_lasts_until_the_next_fault_counts_as_held():
    c = np.full(len(T), 0.01)
    c[(T > 10.0) & (T < 14.0)] = 0.5  # over from the fault's end to 14 s
    c[T > 17.0] = 0.5  # the next fault, at 17 s, puts it over again
    assert held_below(T, c, 10.0) is None  # 3 s below, then over for good
    assert held_below(T, c, 10.0, t_next=17.0) == 4.0  # below from 14 s until the next fault
    c[(T > 15.0) & (T < 15.5)] = 0.5  # over again before the next fault: not held from 14 s
    assert abs(held_below(T, c, 10.0, t_next=17.0) - 5.5) < 1e-9
    # the next fault began before this one ended: the stretches after it are graded as before
    assert held_below(T, c, 10.0, t_next=9.0) is None and held_below(T, c, 10.0) is None


def test_the_next_fault_only_ever_ends_a_stretch_early_never_denies_a_later_one():
    c = np.full(len(T), 0.5)
    c[T > 25.0] = 0.01  # still over when the next fault begins at 20 s, below for good from 25 s
    assert abs(held_below(T, c, 10.0, t_next=20.0) - 15.1) < 1e-9
    assert held_below(T, c, 10.0, t_next=20.0) == held_below(T, c, 10.0)

