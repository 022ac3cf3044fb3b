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


def test_the_profile_counts_the_conv_of_a_one_conv_model_as_its_convolutions(tmp_path):
    """``op_shares`` splits a model's kernel time into its convolutions and
    the rest (what bounds INT8's speed-up): on a model of one conv, the
    convolutions' time is the Conv kernel's share, and the rest is only
    ONNX Runtime's layout reorder around it."""
    from tests.helpers import onnx_select_rgb

    p = bc.op_shares(onnx_select_rgb(tmp_path / "sel.onnx"), 1, 768, runs=2)
    assert p["conv_ms"] > 0
    assert p["conv_ms"] == pytest.approx(p["ms"] * p["percent"]["Conv"] / 100, rel=0.05, abs=0.05)
    assert set(p["percent"]) <= {"Conv", "ReorderInput", "ReorderOutput"}
