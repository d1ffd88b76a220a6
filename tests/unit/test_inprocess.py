"""The in-process loop's own housekeeping (``orchestrator/run/inprocess.py``)."""

import gc

from copath.scenario import load_scenario
from orchestrator.run.inprocess import run_scenario
from tests.conftest import config


def test_a_run_freezes_what_lives_for_it_and_leaves_a_callers_freeze_alone():
    """The objects alive at the start are kept out of the collector's full passes during
    the run and handed back after it; a caller that froze objects itself keeps them frozen."""
    sc = load_scenario(config("e5.5-"))
    assert gc.get_freeze_count() == 0
    res = run_scenario(sc, duration_s=0.5)
    assert res.ok and res.metrics["fleet"]["collisions"] == 0 and res.metrics["sim_time_s"] == 0.5
    assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        mine = gc.get_freeze_count()
        assert mine > 0
        assert run_scenario(sc, duration_s=0.5).ok
        assert 0 < gc.get_freeze_count() <= mine  # still frozen, nothing of the run added (some may have died)
    finally:
        gc.unfreeze()


def test_a_run_collects_the_youngest_generation_less_often_and_restores_the_callers_thresholds():
    """During the run the youngest generation waits for more allocations (fewer passes over the
    records the run keeps); the caller's thresholds come back after it, and a caller that set
    a larger one, or turned the collector's thresholds off, keeps its own during the run."""
    sc = load_scenario(config("e5.5-"))
    before = gc.get_threshold()
    seen = []
    assert run_scenario(sc, duration_s=0.3, on_tick=lambda t, n: seen.append(gc.get_threshold())).ok
    assert seen and all(th[0] > before[0] and th[1:] == before[1:] for th in seen)
    assert gc.get_threshold() == before
    for mine in ((0, before[1], before[2]), (10 ** 6, 3, 4)):
        gc.set_threshold(*mine)
        try:
            seen.clear()
            assert run_scenario(sc, duration_s=0.3, on_tick=lambda t, n: seen.append(gc.get_threshold())).ok
            assert seen and all(th == mine for th in seen)
            assert gc.get_threshold() == mine
        finally:
            gc.set_threshold(*before)
