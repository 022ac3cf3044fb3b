"""benchmarks/ablations.py: the step count that ``--minutes`` picks."""

import pytest

from benchmarks.ablations import steps_in


def test_steps_fill_the_minutes_at_the_slowest_step_rounded_down():
    # 4 min at 51.6 ms a step: 4651 steps, rounded down to 4600 (the H200 run)
    assert steps_in(4, 0.0516, 3, 3) == 4600
    assert steps_in(1, 0.1, 2, 2) == 600


def test_entries_beyond_the_workers_run_in_rounds_that_share_the_minutes():
    one = steps_in(10, 0.2, 2, 2)
    assert steps_in(10, 0.2, 3, 2) == pytest.approx(one / 2, abs=100)
    assert steps_in(10, 0.2, 4, 2) == steps_in(10, 0.2, 3, 2)


def test_a_budget_too_small_still_trains_100_steps():
    assert steps_in(0.01, 1.0, 5, 1) == 100
