"""benchmarks/sfr_chart.py (kind: property): a chart case is written as
the linear file both tools read, ours is measured against its truth edge
by edge, MTF Mapper's table is read with its "not measured" marks left
out, and its absence leaves its half out."""

import numpy as np
import pytest

from benchmarks import sfr_chart

pytestmark = pytest.mark.property


def test_a_small_chart_is_measured_against_its_truth(tmp_path, monkeypatch):
    case = sfr_chart.ChartCase("small", (600, 800), (3, 4), 1.0, (5.0, 9.0), 0.0, 16, True)
    row = sfr_chart.run_case(case, tmp_path, ["accurate"], None, seed=1)
    ours = row["tools"]["ours_accurate"]
    assert row["edges_true"] == 48 and ours["found"] == ours["matched"] == 48
    assert ours["worst"] < 0.1 and abs(ours["bias"]) < 0.1    # noise-free: the method's own bias only
    assert "mtf_mapper" not in row["tools"]


def test_eight_bit_charts_are_png_and_noise_is_seeded(tmp_path):
    case = sfr_chart.ChartCase("b8", (200, 300), (1, 1), 1.0, (5.0,), 0.01, 8, False)
    a, truth, maps = sfr_chart.write_chart(case, tmp_path, seed=3)
    assert maps is None
    import cv2

    img = cv2.imread(str(a), cv2.IMREAD_UNCHANGED)
    assert a.suffix == ".png" and img.dtype == np.uint8 and len(truth) == 4
    (tmp_path / "again").mkdir()
    b, _, _ = sfr_chart.write_chart(case, tmp_path / "again", seed=3)
    assert np.array_equal(img, cv2.imread(str(b), cv2.IMREAD_UNCHANGED))


def test_warp_maps_are_identity_at_zero_and_move_the_corners_in():
    mx, my = sfr_chart.warp_maps((30, 40), 0.0, 0.0)
    yy, xx = np.mgrid[0:30, 0:40]
    assert np.allclose(mx, xx, atol=1e-4) and np.allclose(my, yy, atol=1e-4)
    mx, my = sfr_chart.warp_maps((30, 40), -0.12, 0.0)     # barrel: a corner pixel reads nearer the centre
    assert abs(mx[0, 0] - 20) < 20 and abs(my[0, 0] - 15) < 15 and mx[15, 20] == pytest.approx(20, abs=1e-4)


def test_a_warped_chart_is_matched_through_its_map(tmp_path):
    case = sfr_chart.ChartCase("warp", (600, 800), (3, 4), 1.2, (5.0, 8.0), 0.0, 16, True, (-0.12, 0.1, 0.3))
    row = sfr_chart.run_case(case, tmp_path, ["accurate"], None, seed=1)
    ours = row["tools"]["ours_accurate"]
    assert row["chart"]["warp"] == {"k1": -0.12, "tilt": 0.1, "vignetting": 0.3}
    assert 40 <= ours["matched"] <= 48 and "median" not in ours        # counted; no analytic truth
    assert 0.12 < ours["mtf50_median"] < 0.17                          # the resampling blurs a little


def test_mtf_mappers_table_and_the_matching(tmp_path):
    (tmp_path / "edge_mtf_values.txt").write_text(
        "# MTF Mapper MTF summary\n0 100.0 50.0 0.150000 1 1\n0 300.0 50.0 0.000000 1 1\n1 100.5 150.2 1.000000 1 1\n"
        "2 500.0 500.0 0.2 1 1\n")
    rows, listed = sfr_chart.read_mtf_mapper(tmp_path)
    assert listed == 4 and rows == [(100.0, 50.0, 0.15), (500.0, 500.0, 0.2)]

    class E:
        def __init__(self, c, m):
            self.centre, self.mtf50, self.length = c, m, 100.0

    truth = [E((101.0, 52.0), 0.151), E((900.0, 900.0), 0.2)]
    sides = sfr_chart.match_sides(rows, truth)
    assert sides == [(0, 0.15)]                            # the edge at (500, 500) matches no true side
    pairs = [(m, truth[i].mtf50) for i, m in sides]
    s = sfr_chart.error_stats(sfr_chart.errors_pct(pairs))
    assert s["n"] == 1 and s["bias"] == pytest.approx(-0.6623, abs=1e-3)


def test_the_single_roi_run_is_timed_whole_process(tmp_path):
    t = sfr_chart.time_single_roi(tmp_path, None, runs=1)
    assert set(t) == {"ours"} and len(t["ours"].runs) == 1 and 0 < t["ours"].median < 30


def test_usable_edges_need_a_slant_and_a_whole_phase_cycle():
    """ISO 12233's 4× ESF needs the edge to cross at least one whole pixel
    phase along its length: 54 px at 0.6° cross 0.57 px (unusable), at 1.1°
    1.04 px (usable); slants outside 1–44° are refused whatever the length."""
    assert not sfr_chart.usable(0.6, 54.0) and sfr_chart.usable(1.1, 54.0)
    assert not sfr_chart.usable(0.9, 1000.0) and not sfr_chart.usable(44.5, 100.0)
    assert [sfr_chart.axis_slant(a) for a in (5.0, 85.0, 95.0, -3.0, 180.5)] == pytest.approx([5.0, 5.0, 5.0, 3.0, 0.5])


def test_mtf_mapper_edges_take_its_angle_and_corner(tmp_path):
    (tmp_path / "edge_mtf_values.txt").write_text(
        "0 434.6 1062.1 0.358 435.3 1035.1\n0 446.4 1034.9 1.000 457.3 1034.9\n1 500.0 500.0 0.30 500.0 450.0\n")
    (tmp_path / "edge_sfr_values.txt").write_text(
        "0 434.6 1062.1 0.600 0.6 1 1\n0 446.4 1034.9 0.046 83.5 1 1\n1 500.0 500.0 84.0 2.0 1 1\n")
    edges = sfr_chart.mtf_mapper_edges(tmp_path)
    assert len(edges) == 2                                     # the 1.0 ("not measured") left out
    assert edges[0]["slant_deg"] == pytest.approx(0.6) and edges[0]["length_px"] == pytest.approx(54.0, abs=0.1)
    assert edges[1]["slant_deg"] == pytest.approx(6.0) and edges[1]["length_px"] == pytest.approx(100.0)
    j = sfr_chart.judged(edges)
    assert j["measured"] == 2 and j["usable"] == 1 and j["unusable_slant_deg"] == [0.6, 0.6]


def test_sides_shown_whole_follow_the_warp():
    """Unwarped, every side of the chart is shown whole; shifted half a
    frame sideways, only the sides of the squares still inside are."""
    from calibration.sfr.synthetic import render_square_chart

    ch = render_square_chart((300, 400), (2, 4), sigma_px=1.0, angles_deg=(5.0,))
    yy, xx = np.mgrid[0:300, 0:400].astype(np.float32)
    assert len(sfr_chart.sides_in_frame(list(ch.edges), (xx, yy), (300, 400))) == 32
    whole = sfr_chart.sides_in_frame(list(ch.edges), (xx + 200.0, yy), (300, 400))   # shows columns 2 and 3
    assert {ch.edges[k].square % 4 for k in whole} == {2, 3} and len(whole) == 16
