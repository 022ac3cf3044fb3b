"""benchmarks/ablations.py: the step count that ``--minutes`` picks (kind: property)."""

import pytest

from benchmarks import ablations
from benchmarks.ablations import ENTRIES, entry_model, steps_in

pytestmark = pytest.mark.property


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


@pytest.mark.parametrize("name", list(ENTRIES))
def test_every_entry_builds_its_network_and_is_in_the_table(name):
    """A typo in an entry's arguments would fail only after the other
    entries' training; the docstring's table names every entry."""
    from restoration.nn.macs import macs_per_pixel
    from restoration.nn.network import build_model

    variant, kwargs, placement = entry_model(name)
    model = build_model(variant, **kwargs)
    kmac = macs_per_pixel(model, (16, 16)) / 1e3
    # the export's 2-core budget, but for the entries that measure what capacity buys past it
    assert kmac <= (80 if name.endswith("large") else 20)
    assert f"\n{name} " in ablations.__doc__
