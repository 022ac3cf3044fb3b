"""benchmarks/correction.py: how the sweep spreads its runs (kind: property)."""

import pytest

import benchmarks.correction as bc

pytestmark = pytest.mark.property


def test_runs_alternate_between_models_over_two_passes_the_second_reversed(monkeypatch):
    """3 runs over tiles (448, 1024): 2 runs each on the way up, alternating
    a/b at each tile, 1 on the way down; one cold run with memory per
    (model, tile) on its first visit, one untimed run on the second."""
    calls = []

    class Stage:
        def __init__(self, name, tile):
            self.name, self.tile = name, tile

        def tiling(self):
            return (self.tile, 32, 4)

    monkeypatch.setattr(bc, "_stage", lambda path, frame, threads, tile: Stage(path, tile))

    def run(stage, frame, memory=False):
        calls.append((stage.name, stage.tile, memory))
        return {"seconds": float(len(calls)), "model_seconds": 0.5, "peak_rss_delta_mib": 1.0}

    monkeypatch.setattr(bc, "_run", run)

    class Frame:
        class data:
            shape = (100, 200, 3)

    out = bc.sweep_models({"a": "a", "b": "b"}, Frame, 2, 3, [448, 1024], log=lambda m: None)
    timed = [(n, t) for n, t, m in calls]
    assert timed == [("a", 448), ("b", 448), ("a", 448), ("b", 448), ("a", 448), ("b", 448),
                     ("a", 1024), ("b", 1024), ("a", 1024), ("b", 1024), ("a", 1024), ("b", 1024),
                     ("a", 1024), ("b", 1024), ("a", 1024), ("b", 1024),
                     ("a", 448), ("b", 448), ("a", 448), ("b", 448)]
    assert [m for *_, m in calls].count(True) == 4          # one cold run per (model, tile)
    # the cold/untimed run of each visit is not among the timed runs: 3 per (model, tile)
    assert {(t, n): len(out[t][n]["runs_s"]) for t in out for n in out[t]} == {
        (448, "a"): 3, (448, "b"): 3, (1024, "a"): 3, (1024, "b"): 3}
    assert out[448]["a"]["runs_s"] == [3.0, 5.0, 19.0] and out[448]["a"]["cold_s"] == 1.0
