"""Chart analysis: edge detection, field positions, sagittal/tangential
orientation, field maps (kind: property), and the real charts of the
shared data (kind: published)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.sfr.esfr import SfrError
from calibration.sfr.chart import GRID, classify_orientation, find_edges, measure_chart, measure_chart_bayer, short_reason
from calibration.sfr.synthetic import mtf50_of
from tests.helpers import data_file, warped_square_chart


def _chart(h=600, w=800, rows=4, cols=5, angle=5.0, sigma=1.0, ss=8, dark=0.2, light=0.8):
    """Slanted dark squares on a light ground, blurred by a Gaussian of
    ``sigma`` px and integrated over square pixels (supersampled ×ss)."""
    import cv2

    big = np.full((h * ss, w * ss), light, np.float32)
    side = 0.5 * min(h / rows, w / cols) * ss
    centres = []
    for r in range(rows):
        for c in range(cols):
            cy, cx = (r + 0.5) * h / rows * ss, (c + 0.5) * w / cols * ss
            box = cv2.boxPoints(((cx, cy), (side, side), angle))
            cv2.fillConvexPoly(big, np.round(box * 16).astype(np.int32), dark, lineType=cv2.LINE_AA, shift=4)
            centres.append((cx / ss, cy / ss))
    big = cv2.GaussianBlur(big, (0, 0), sigma * ss)
    img = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
    return img.astype(np.float64), centres


@pytest.mark.property
def test_finds_every_side_of_every_square_and_measures_it():
    img, centres = _chart()
    res = measure_chart(img)
    assert len(res.edges) == 4 * len(centres)          # 4 slanted sides per square, no extras
    truth = mtf50_of(1.0, 5.0)
    m = np.array([r.mtf50 for _, r in res.edges])
    assert np.median(np.abs(m / truth - 1)) < 0.02      # supersampled rendering, not exact
    assert all(3.0 < abs(r.angle_deg) < 7.0 for _, r in res.edges)


@pytest.mark.property
def test_field_position_and_orientation():
    img, _ = _chart()
    rois = find_edges(img)
    h, w = img.shape
    for e in rois:
        cx, cy = e.centre
        r = math.hypot(cx - w / 2, cy - h / 2) / (0.5 * math.hypot(w, h))
        assert e.radius == pytest.approx(r, abs=1e-9)
        assert e.field_angle_deg == pytest.approx(math.degrees(math.atan2(h / 2 - cy, cx - w / 2)), abs=1e-9)
        # on the horizontal axis through the centre, vertical edges are tangential
        if abs(cy - h / 2) < 0.1 * h and abs(cx - w / 2) > 0.2 * w:
            assert e.orientation == ("tangential" if e.direction == "vertical" else "sagittal")


@pytest.mark.property
def test_orientation_convention():
    # an edge perpendicular to the radius (normal along it): tangential
    assert classify_orientation(0.0, 1.0, 0.6, 0.0) == "tangential"
    assert classify_orientation(1.0, 0.0, 0.6, 90.0) == "tangential"   # above centre, horizontal edge
    assert classify_orientation(0.0, 1.0, 0.6, 90.0) == "sagittal"
    assert classify_orientation(0.0, 1.0, 0.01, 0.0) == "axial"


@pytest.mark.property
def test_field_maps_on_the_15_by_20_grid():
    img, centres = _chart()
    res = measure_chart(img)
    m = res.field_map("sfra")
    assert m.shape == GRID
    assert np.isfinite(m).sum() >= len(centres)          # every square's region has a value
    assert np.isnan(m).sum() > 0                         # regions without edges stay NaN
    t = res.field_map("mtf50", "tangential")
    s = res.field_map("mtf50", "sagittal")
    assert np.isfinite(t).any() and np.isfinite(s).any()
    d = res.to_dict()
    assert len(d["maps"]["sfra"]["all"]) == GRID[0] and len(d["maps"]["sfra"]["all"][0]) == GRID[1]
    assert {"freq", "sfr", "mtf50", "sfra", "angle_deg", "roi", "field", "orientation", "warnings"} <= set(d["edges"][0])


@pytest.mark.published
def test_real_charts():
    import cv2

    # reference: the "Camera SFR & OECF" chart's tilted dark square has four edges
    img = cv2.imread(str(data_file("edges", "sfrmat3_ISO_DSC_300a.jpg")))[..., ::-1]
    res = measure_chart(img, encoding="srgb")
    assert len(res.edges) == 4
    # the ISO 12233:2023 digital chart: pinwheel blades and the central square
    img = cv2.imread(str(data_file("edges", "sfrmat5_ISO_12233-2023_chart_digital.jpg")))[..., ::-1]
    res = measure_chart(img, encoding="srgb")
    assert len(res.edges) >= 60                               # MTF Mapper 0.7.38 measures 5
    assert all(0.2 < r.mtf50 < 0.5 for _, r in res.edges)   # a sharp digital file
    # a webcam's photo of the older ISO 12233 resolution chart, barrel-distorted: the frame's
    # curved edges in straight pieces, the slanted bars; MTF Mapper 0.7.38 measures 15 edges here
    img = cv2.imread(str(data_file("edges", "rayxie_webcam_iso12233_original_img.bmp")))[..., ::-1]
    res = measure_chart(img, encoding="srgb")
    assert len(res.edges) >= 15
    assert all(0.15 < r.mtf50 < 0.5 for _, r in res.edges)
    reasons = {short_reason(why) for _, why in res.skipped}
    assert reasons and all(reasons)                           # every refusal says why


@pytest.mark.property
def test_bad_chart_input():
    with pytest.raises(SfrError, match="uniform"):
        find_edges(np.full((100, 100), 0.5))
    img, _ = _chart(h=200, w=200, rows=1, cols=1)
    img[5, 5] = np.nan
    with pytest.raises(SfrError, match="NaN"):
        find_edges(img)


@pytest.mark.property
def test_each_side_is_measured_whole_and_recovers_its_truth():
    """On an exactly rendered chart every side is found and measured over
    all its length but the corners (≥ 85 % of it: the SFR's noise falls as
    the square root of the rows), and its MTF50 is the truth within 0.1 %
    noise-free with the default method."""
    from calibration.sfr.synthetic import render_square_chart

    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.2, angles_deg=(4.0, 7.0, 11.0), side=0.55)
    res = measure_chart(ch.image)
    assert len(res.edges) == len(ch.edges) == 48 and not res.skipped
    centres = np.array([e.centre for e in ch.edges])
    for roi, r in res.edges:
        i = int(np.argmin(np.hypot(*(centres - np.array(roi.centre)).T)))
        truth = ch.edges[i]
        along = roi.h if roi.direction == "vertical" else roi.w
        assert along >= 0.85 * truth.length * math.cos(math.radians(truth.angle_deg))
        assert r.mtf50 == pytest.approx(truth.mtf50, rel=1e-3)


@pytest.mark.property
def test_a_steeply_slanted_side_keeps_most_of_its_length():
    """Slanted 22–38°, a whole side's wide box reaches the square's
    neighbouring sides; the ROI narrows across before it shortens, so each
    side keeps at least 65 % of its length (half a side scatters the MTF50
    1.4× more), and is measured to its truth."""
    from calibration.sfr.synthetic import render_square_chart

    ch = render_square_chart((750, 1000), (3, 4), sigma_px=1.0, angles_deg=(22.0, 30.0, 38.0))
    res = measure_chart(ch.image)
    assert len(res.edges) == len(ch.edges) == 48
    centres = np.array([e.centre for e in ch.edges])
    for roi, r in res.edges:
        truth = ch.edges[int(np.argmin(np.hypot(*(centres - np.array(roi.centre)).T)))]
        along = roi.h if roi.direction == "vertical" else roi.w
        assert along >= 0.65 * truth.length * math.cos(math.radians(truth.angle_deg)), (along, truth)
        assert r.mtf50 == pytest.approx(truth.mtf50, rel=2e-3)


@pytest.mark.property
def test_the_annotated_chart_draws_each_edge_and_each_skip_with_its_reason():
    """One line per measured edge, along its fitted edge and coloured by its
    MTF50 on the colour bar's scale, its value printed; each skipped
    candidate boxed with the number of its reason's kind in the legend."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.colors import to_rgba

    from calibration.sfr.chart import annotate_chart, short_reason
    from calibration.sfr.synthetic import render_square_chart

    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.0, angles_deg=(5.0, 9.0), side=0.5)
    res = measure_chart(ch.image)
    assert len(res.edges) == 48
    # two candidates the measurement refused, of two kinds
    from calibration.sfr.chart import EdgeROI

    res.skipped = [(EdgeROI(10, 10, 20, 20, 5.0, "vertical", 0.9, 135.0, "sagittal", 0), "uniform ROI: every pixel is 0.8"),
                   (EdgeROI(40, 10, 20, 20, 5.0, "vertical", 0.9, 135.0, "sagittal", 0),
                    "edge angle 0.30° gives less than one whole phase cycle over 20 rows (needs ≥ 10 rows)")]
    fig = annotate_chart(res, ch.image)
    ax = fig.axes[0]
    lines = [ln for ln in ax.lines if ln.get_linewidth() == 2.0]
    assert len(lines) == 48
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    vals = [r.mtf50 for _, r in res.edges]
    norm, cmap = Normalize(*np.percentile(vals, [2, 98])), plt.get_cmap("turbo")
    for ln, (roi, r) in zip(lines, res.edges):
        assert to_rgba(ln.get_color()) == pytest.approx(cmap(norm(r.mtf50)))
        x, y = ln.get_data()
        assert roi.x - 1 <= np.mean(x) <= roi.x + roi.w + 1 and roi.y - 1 <= np.mean(y) <= roi.y + roi.h + 1
    texts = {t.get_text() for t in ax.texts}
    assert {f"{r.mtf50:.3f}" for _, r in res.edges} <= texts and {"1", "2"} <= texts
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend == [f"1: {short_reason(res.skipped[0][1])} (1)", "2: edge untilted (under one phase cycle) (1)"]


@pytest.mark.property
def test_unused_edge_pieces_are_reported_with_their_reason():
    """An untilted square's sides are found but not measured, each listed
    with its slant; a slanted square beside it is measured whole."""
    from calibration.sfr.synthetic import render_square_chart

    ch = render_square_chart((400, 800), (1, 2), sigma_px=1.0, angles_deg=(0.0, 6.0), side=0.5)
    rejected = []
    rois = find_edges(ch.image, rejected=rejected)
    assert len(rois) == 4 and all(r.centre[0] > 400 for r in rois)
    assert len(rejected) == 4 and all(e.centre[0] < 400 for e, _ in rejected)
    assert all("slanted 0.0°" in why and "outside 1–44°" in why for _, why in rejected)
    res = measure_chart(ch.image)
    assert len(res.edges) == 4 and len(res.skipped) == 4
    assert {short_reason(w) for _, w in res.skipped} == {"slant out of range"}


@pytest.mark.property
def test_a_chart_measured_on_worker_processes_equals_one_measured_here():
    """The image and settings go to each worker once (the executor's
    payload); the results are the serial ones, bit for bit."""
    from calibration.sfr.synthetic import render_square_chart
    from isp.runtime.executor import create_executor

    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.2, angles_deg=(5.0, 8.0))
    serial = measure_chart(ch.image)
    with create_executor("processes", workers=2) as ex:
        pooled = measure_chart(ch.image, executor=ex)
    assert [r.centre for r, _ in pooled.edges] == [r.centre for r, _ in serial.edges]
    assert [s.mtf50 for _, s in pooled.edges] == [s.mtf50 for _, s in serial.edges]
    assert all(np.array_equal(a.sfr, b.sfr) for (_, a), (_, b) in zip(pooled.edges, serial.edges))


@pytest.mark.property
@pytest.mark.parametrize("warp", ["perspective", "barrel", "barrel_vignetting"])
def test_every_side_is_found_through_perspective_distortion_and_vignetting(warp):
    """A chart seen at an angle (perspective), through barrel distortion
    (curved sides, k = 0.08 at the frame's half-width) and with 35 %
    vignetting: every side of every square is still found and measured."""
    out = warped_square_chart(warp)
    res = measure_chart(out.astype(np.float64))
    assert len(res.edges) == 48 and not res.skipped
    assert all(0.15 < r.mtf50 < 0.25 for _, r in res.edges)     # σ 1 px: 0.180, moved a little by the resampling


@pytest.mark.property
def test_a_mosaic_chart_measured_on_worker_processes_equals_one_measured_here():
    from calibration.sfr.synthetic import render_square_chart
    from isp.frame import CFA
    from isp.runtime.executor import create_executor

    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.5, angles_deg=(5.0, 8.0))
    serial = measure_chart_bayer(ch.image, CFA.RGGB)
    with create_executor("processes", workers=2) as ex:
        pooled = measure_chart_bayer(ch.image, CFA.RGGB, executor=ex)
    assert len(serial.edges) == 48
    assert [s.mtf50 for _, s in pooled.edges] == [s.mtf50 for _, s in serial.edges]


@pytest.mark.property
def test_the_roi_search_percentiles_are_numpys():
    """The detector's partial-sort percentiles equal np.percentile, bit for
    bit, on integer codes and floats."""
    from calibration.sfr.chart import _percentiles

    rng = np.random.default_rng(3)
    for a in (rng.integers(0, 65536, (37, 41)).astype(np.uint16), rng.normal(size=1001) * 1e3,
              rng.integers(0, 256, 7).astype(np.uint8), np.array([2.5])):
        for q in ((5, 95), (1, 99), (0, 100), (50, 50)):
            got, want = _percentiles(a, q), np.percentile(a, q)
            assert got.dtype == want.dtype and np.array_equal(got, want)


@pytest.mark.property
def test_collinear_pieces_join_as_the_test_of_every_pair_joins_them():
    """The pieces of one edge are joined as when every pair is tested: the
    pre-selection of the pairs misses none, at the thresholds included."""
    from calibration.sfr.chart import _join_collinear

    def every_pair(seg, cos_tol=math.cos(math.radians(1.5)), offset=1.5, gap=6.0):
        n = len(seg)
        d = seg[:, 1] - seg[:, 0]
        length = np.hypot(d[:, 0], d[:, 1])
        u = d / np.maximum(length, 1e-9)[:, None]
        label = np.arange(n)
        for i in range(n - 1):
            rel = seg[i + 1:] - seg[i, 0]
            off = np.abs(rel[..., 0] * u[i, 1] - rel[..., 1] * u[i, 0]).max(axis=1)
            t = rel @ u[i]
            ok = ((np.abs(u[i + 1:] @ u[i]) >= cos_tol) & (off <= offset)
                  & (t.min(axis=1) <= length[i] + gap) & (t.max(axis=1) >= -gap))
            for j in np.flatnonzero(ok) + i + 1:
                label[label == label[j]] = label[i]
        return sorted(len(np.flatnonzero(label == k)) for k in np.unique(label))

    rng = np.random.default_rng(5)
    joins = 0
    for _ in range(20):
        n = int(rng.integers(2, 120))
        p0 = rng.uniform(0, 2000, (n, 2))
        ang = rng.choice([0.05, 1.6, 0.7]) + rng.normal(0, 0.02, n)
        seg = np.stack([p0, p0 + rng.uniform(5, 300, n)[:, None] * np.stack([np.cos(ang), np.sin(ang)], 1)], 1)
        more = []
        for k in rng.integers(0, n, n // 2):           # continuations at and around the thresholds
            d = seg[k, 1] - seg[k, 0]
            u = d / np.hypot(*d)
            a = (seg[k, 1] + rng.choice([6.0, -6.0, rng.uniform(-9, 9)]) * u
                 + rng.choice([1.5, -1.5, rng.uniform(-2, 2)]) * np.array([u[1], -u[0]]))
            more.append([a, a + rng.uniform(5, 100) * u])
        seg = np.concatenate([seg, more])[rng.permutation(n + len(more))]
        sizes = every_pair(seg)
        joined = _join_collinear(seg)
        assert len(joined) == len(sizes)
        joins += len(seg) - len(sizes)
    assert joins > 50
