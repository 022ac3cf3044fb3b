"""benchmarks/detection_limits.py (kind: property): every built-in registry
effect has a ladder, and the limit is the lowest rung of the unbroken run of
detections from the top, found without climbing below two misses in a row."""

import pytest

from benchmarks import detection_limits as D
from calibration.loop import effects

pytestmark = pytest.mark.property


def test_every_built_in_effect_has_an_ascending_ladder():
    built_in = {n for n, c in effects.EFFECTS.entries().items() if c.__module__ == effects.__name__}
    assert built_in == set(D.LADDERS)
    for unit, rungs, make in D.LADDERS.values():
        assert list(rungs) == sorted(rungs) and rungs[0] > 0
        kw, ops, channels = make(rungs[0])
        assert set(channels) <= {"R", "G", "B", "L"}


@pytest.mark.parametrize("detected, limit, tried, above", [
    ({8.0, 6.0, 5.0, 4.0}, 4.0, [8.0, 6.0, 5.0, 4.0, 3.0, 2.0], []),      # two misses below the limit: stop
    ({8.0, 6.0, 4.0}, 6.0, [8.0, 6.0, 5.0, 4.0, 3.0, 2.0], []),           # a miss breaks the run
    ({6.0}, 6.0, [8.0, 6.0, 5.0, 4.0], [8.0]),                             # the top missed, the next found
    (set(), None, [8.0, 6.0, 5.0, 4.0, 3.0, 2.0, 1.0], []),               # nothing: every rung, above the ladder
])
def test_the_limit_is_the_bottom_of_the_run_down_from_the_highest_detection(monkeypatch, detected, limit, tried,
                                                                            above):
    seen = []

    def fake(effect, m, noise, grid, seed, executor):
        seen.append(m)
        return {"added": [effect] if m in detected else ["sharpening"], "after_over_floor": 1.0, "edges": 70}

    monkeypatch.setattr(D, "run_one", fake)
    out = D.ladder("focus_shift", 0.003, (5, 7), None, lambda msg: None)
    assert out["limit"] == limit and out["missed_above"] == above
    assert sorted(set(seen), reverse=True) == tried
    assert out["named_instead"] == ["sharpening"]


def test_a_limit_at_either_end_of_the_ladder_says_so():
    rung = lambda m, ok: {"magnitude": m, "detected": ok}   # noqa: E731
    assert D.limit_text({"limit": 2.0, "rungs": [rung(1.0, False), rung(2.0, True), rung(3.0, True)]}) == "2"
    assert D.limit_text({"limit": 1.0, "rungs": [rung(1.0, True), rung(2.0, True)]}) == "≤ 1"
    assert D.limit_text({"limit": None, "rungs": [rung(2.0, False), rung(3.0, False)]}) == "> 3"
    assert D.limit_text({"limit": 2.0, "missed_above": [3.0],
                         "rungs": [rung(1.0, False), rung(2.0, True), rung(3.0, False)]}) == "2 (missed at 3)"
