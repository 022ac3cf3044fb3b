"""Speed of the e-SFR measurement (calibration.sfr.esfr), 2 threads.

1. One edge: a 100×200 px ROI (100 rows along a 5° edge, σ = 1 px,
   1 % noise, 10-bit codes in float32), three warm-up calls, then the
   median of ``--runs`` calls of :func:`calibration.sfr.esfr.measure_sfr`
   (with the fastest and slowest); also with ``bootstrap=50``.
2. A whole simulated 12 MP chart: a 4000×3000 float32 image with ``--edges``
   slanted-edge ROIs (alternating vertical/horizontal, both polarities,
   angles 3–11°, blur σ 0.7–2 px growing towards the corners, 1 % noise)
   whose boxes are given. All ROIs are measured serially, with 2 threads and
   with 2 processes (one run each); the fastest of the three ways is the
   chart time. Each MTF50 is also compared with the analytic truth.
3. The same 12 MP frame as a chart to be found: 6 × 8 slanted dark squares
   (192 edges), detection and measurement by
   :func:`calibration.sfr.chart.measure_chart`.

Prints progress, then one JSON object as its last line:
``per_edge_ms, per_edge_bootstrap50_ms`` (each ``{median, min, max, n}``),
``roi, chart_edges, chart_serial_s,
chart_threads2_s, chart_procs2_s, chart_best_s, target_s, chart_ok,
mtf50_median_abs_err_pct, mtf50_worst_abs_err_pct, detected_chart_edges,
detected_chart_s, detected_chart_ok, runs, threads``.

Usage: python -m benchmarks.sfr [--runs 50] [--edges 120]
"""

from __future__ import annotations

from benchmarks import _harness

THREADS = 2
if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(THREADS)

import multiprocessing as mp  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from calibration.sfr.esfr import measure_sfr  # noqa: E402
from calibration.sfr.synthetic import mtf50_of, render_slanted_edge  # noqa: E402

CHART = (3000, 4000)  # rows, columns: 12 MP
ROI_ALONG, ROI_ACROSS = 200, 100  # ROI of the chart edges: 200 px along, 100 px across
TARGET_S = 2.0


def to_codes(img: np.ndarray, rng, bits: int = 10) -> np.ndarray:
    """Add 1 % noise and quantise to ``bits`` (values stay float32 in [0, 1])."""
    top = 2**bits - 1
    noisy = img + rng.normal(0.0, 0.01, img.shape)
    return (np.round(np.clip(noisy, 0, 1) * top) / top).astype(np.float32)


def one_edge(runs: int) -> tuple[_harness.Spread, _harness.Spread]:
    """Milliseconds per measurement of one ROI, without and with ``bootstrap=50``."""
    rng = np.random.default_rng(0)
    roi = to_codes(render_slanted_edge((100, 200), 5.0, 1.0), rng)
    plain = _harness.measure(lambda: measure_sfr(roi, method="iso"), runs=runs, warmup=3)
    seeds = iter(range(10 ** 6))
    boot = _harness.measure(lambda: measure_sfr(roi, method="iso", bootstrap=50, rng=next(seeds)), runs=max(3, runs // 10),
                            warmup=0)
    return plain.map(lambda s: 1e3 * s), boot.map(lambda s: 1e3 * s)


def make_chart(n_edges: int, seed: int = 1):
    """(image, boxes, truths): ``boxes`` are (x, y, w, h); truths (σ, angle)."""
    rng = np.random.default_rng(seed)
    h, w = CHART
    img = np.full(CHART, 0.5, dtype=np.float64)
    cols = int(np.ceil(np.sqrt(n_edges * w / h)))
    rows = int(np.ceil(n_edges / cols))
    cell_w, cell_h = w // cols, h // rows
    boxes, truths = [], []
    for i in range(n_edges):
        r, c = divmod(i, cols)
        vertical = (r + c) % 2 == 0
        bw, bh = (ROI_ACROSS, ROI_ALONG) if vertical else (ROI_ALONG, ROI_ACROSS)
        x = c * cell_w + (cell_w - bw) // 2
        y = r * cell_h + (cell_h - bh) // 2
        cx, cy = (x + bw / 2) / w - 0.5, (y + bh / 2) / h - 0.5
        sigma = 0.7 + 1.3 * min(1.0, 2 * np.hypot(cx, cy))  # blur grows with field
        angle = 3.0 + 8.0 * rng.random()
        lo, hi = (0.15, 0.75) if i % 3 else (0.75, 0.15)
        patch = render_slanted_edge((bh, bw), angle, sigma, low=lo, high=hi, horizontal=not vertical)
        img[y : y + bh, x : x + bw] = patch
        boxes.append((x, y, bw, bh))
        truths.append((sigma, angle))
    return to_codes(img, rng), boxes, truths


_CHART = None  # the image, shared with forked workers


def _measure_box(box):
    return measure_sfr(_CHART, box=box, method="iso").mtf50


def chart(n_edges: int) -> dict:
    global _CHART
    t0 = time.perf_counter()
    _CHART, boxes, truths = make_chart(n_edges)
    print(f"chart {CHART[1]}×{CHART[0]} with {len(boxes)} edges rendered in {time.perf_counter() - t0:.1f} s")
    measure_sfr(_CHART, box=boxes[0], method="iso")

    t0 = time.perf_counter()
    serial = [_measure_box(b) for b in boxes]
    t_serial = time.perf_counter() - t0

    t0 = time.perf_counter()
    with ThreadPoolExecutor(THREADS) as ex:
        threaded = list(ex.map(_measure_box, boxes))
    t_threads = time.perf_counter() - t0

    t0 = time.perf_counter()
    with ProcessPoolExecutor(THREADS, mp_context=mp.get_context("fork")) as ex:
        procs = list(ex.map(_measure_box, boxes, chunksize=max(1, len(boxes) // 8)))
    t_procs = time.perf_counter() - t0
    assert np.allclose(serial, threaded) and np.allclose(serial, procs)

    err = np.abs([m / mtf50_of(s, a) - 1 for m, (s, a) in zip(serial, truths)])
    best = min(t_serial, t_threads, t_procs)
    return {
        "chart_edges": len(boxes),
        "chart_serial_s": round(t_serial, 3),
        "chart_threads2_s": round(t_threads, 3),
        "chart_procs2_s": round(t_procs, 3),
        "chart_best_s": round(best, 3),
        "target_s": TARGET_S,
        "chart_ok": best <= TARGET_S,
        "mtf50_median_abs_err_pct": round(100 * float(np.median(err)), 3),
        "mtf50_worst_abs_err_pct": round(100 * float(np.max(err)), 3),
    }


def detected_chart(grid=(6, 8), sigma=1.2, seed=2) -> dict:
    """A 12 MP image of slanted dark squares (anti-aliased, Gaussian blur,
    1 % noise, 10-bit): time :func:`calibration.sfr.chart.measure_chart`,
    detection included."""
    from calibration.sfr.chart import measure_chart

    rng = np.random.default_rng(seed)
    h, w = CHART
    img = np.full(CHART, 0.7, np.float32)
    rows, cols = grid
    side = 0.55 * min(h / rows, w / cols)
    for r in range(rows):
        for c in range(cols):
            box = cv2.boxPoints((((c + 0.5) * w / cols, (r + 0.5) * h / rows), (side, side), 5.0))
            cv2.fillConvexPoly(img, np.round(box * 16).astype(np.int32), 0.2, lineType=cv2.LINE_AA, shift=4)
    img = cv2.GaussianBlur(img, (0, 0), sigma)
    img = to_codes(img.astype(np.float64), rng)
    measure_chart(img[:600, :800], method="iso")  # warm-up (imports)
    t0 = time.perf_counter()
    res = measure_chart(img, method="iso")
    dt = time.perf_counter() - t0
    return {"detected_chart_squares": rows * cols, "detected_chart_edges": len(res.edges),
            "detected_chart_skipped": len(res.skipped), "detected_chart_s": round(dt, 3),
            "detected_chart_ok": dt <= TARGET_S}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=50, help="timed runs of the single edge (≥ 20)")
    ap.add_argument("--edges", type=int, default=120, help="edges on the 12 MP chart (≥ 100)")
    args = ap.parse_args(argv)
    runs = max(20, args.runs)
    per_edge, per_edge_boot = one_edge(runs)
    print(f"one 100×200 ROI: {per_edge.median:.2f} ms median of {runs} ({per_edge.min:.2f}–{per_edge.max:.2f}); "
          f"bootstrap=50: {per_edge_boot.median:.0f} ms")
    out = {"per_edge_ms": per_edge.as_dict(3), "per_edge_bootstrap50_ms": per_edge_boot.as_dict(1)}
    out["roi"] = "100x200 (rows x cols)"
    res = chart(args.edges)
    print(
        f"chart: serial {res['chart_serial_s']} s, 2 threads {res['chart_threads2_s']} s, "
        f"2 processes {res['chart_procs2_s']} s (target ≤ {TARGET_S} s)"
    )
    out.update(res)
    det = detected_chart()
    print(f"chart with detection: {det['detected_chart_edges']} edges of {det['detected_chart_squares']} squares "
          f"found and measured in {det['detected_chart_s']} s")
    out.update(det)
    out.update({"runs": runs, "threads": THREADS})
    return _harness.publish("sfr", out, args, argv)


if __name__ == "__main__":
    main()
