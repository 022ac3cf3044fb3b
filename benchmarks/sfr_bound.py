"""What a chart's edges allow: the Cramér–Rao bound on a slanted edge's
MTF50, pooled over the accuracy sweep of :mod:`benchmarks.sfr_chart`.

No estimator of MTF50 that is unbiased can scatter less, edge by edge, than
the Cramér–Rao bound of the edge's own pixels, and the bound used here is
generous to the estimator: it *knows* the blur is a Gaussian of unknown σ
(one number, where an SFR tool assumes no form), the pixels are the whole
side of the square (no corners cut), and only five things are unknown (σ,
the edge's offset and angle, the dark and bright levels). Its Fisher
information is ``JᵀJ / σ_n²`` with ``J`` the image's derivatives in those
five (central differences of the exact render,
:func:`calibration.sfr.synthetic.render_slanted_edge`, or the
point-sampled ``Φ(d/σ)``), ``σ_n`` the added noise and the quantisation's
(``LSB/√12``: 8 bits leave σ_n = 0.11 % of the range where no noise is
added). The bound on σ goes to MTF50 through ``dMTF50/dσ``
(:func:`calibration.sfr.synthetic.mtf50_of`, aperture included).

For every chart of the sweep (2000 × 1500, 6 × 8 squares of side 137.5 px,
their angles cycling through the sweep's 16, σ 0.6–2 px, noise 0–1 %, 8 and
16 bits, with and without the pixel aperture) each of the 192 edges gets its
bound ``s``; an efficient unbiased estimator's errors would be drawn from
``N(0, s)``. Pooled as the sweep pools the tools (SNR ≥ 100, and per noise
level), the script reports the median, 95th percentile and expected worst
of ``|error|`` (%, by drawing those errors, 200 sets), beside the issue's
targets and the tools' figures of the recorded sweep
(``benchmarks/results/sfr_chart.json``) where there is one.

Usage::

    python -m benchmarks.sfr_bound [--draws 200]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":
    _harness.pin_threads(2)

import json  # noqa: E402
from functools import lru_cache  # noqa: E402

import numpy as np  # noqa: E402
from scipy.special import ndtr  # noqa: E402

from benchmarks.sfr_chart import STEP, SWEEP_ANGLES, TARGETS, sweep_cases  # noqa: E402
from calibration.sfr.synthetic import mtf50_of, render_slanted_edge  # noqa: E402

#: the sweep's square side, px (``render_square_chart``'s side 0.55 of its 250-px cells)
SIDE_PX = 0.55 * 250.0
#: columns on each side of the edge, px: the ESF is flat past 8σ of the widest blur
HALF_WIDTH_PX = 24
LOW, HIGH = 0.2, 0.8


def edge_image(rows: int, cols: int, angle_deg: float, sigma: float, offset: float, low: float, high: float,
               aperture: bool) -> np.ndarray:
    """A vertical-ish edge through column ``offset`` of the middle row:
    exact with the pixel aperture, point-sampled ``Φ(d/σ)`` without."""
    if aperture:
        return render_slanted_edge((rows, cols), angle_deg, sigma, low=low, high=high,
                                   center=(offset, (rows - 1) / 2.0))
    th = np.radians(angle_deg)
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    d = (x - offset) * np.cos(th) - (y - (rows - 1) / 2.0) * np.sin(th)
    return low + (high - low) * ndtr(d / sigma)


@lru_cache(maxsize=None)
def sigma_information(angle_deg: float, sigma: float, aperture: bool) -> float:
    """``[(JᵀJ)⁻¹]_σσ`` of one side (noise σ_n = 1): the variance bound on σ
    per unit noise variance, the other four unknowns free."""
    rows = int(SIDE_PX * np.cos(np.radians(angle_deg)))
    cols = 2 * HALF_WIDTH_PX + 1
    x0 = np.array([sigma, HALF_WIDTH_PX + 0.3, angle_deg, LOW, HIGH])
    steps = np.array([1e-4 * sigma, 1e-4, 1e-4, 1e-4, 1e-4])
    cols_j = []
    for k in range(5):
        up, dn = x0.copy(), x0.copy()
        up[k] += steps[k]
        dn[k] -= steps[k]
        ip = edge_image(rows, cols, up[2], up[0], up[1], up[3], up[4], aperture)
        im = edge_image(rows, cols, dn[2], dn[0], dn[1], dn[3], dn[4], aperture)
        cols_j.append(((ip - im) / (2 * steps[k])).ravel())
    j = np.stack(cols_j, axis=1)
    return float(np.linalg.inv(j.T @ j)[0, 0])


def mtf50_bound_pct(angle_deg: float, sigma: float, aperture: bool, noise: float, bits: int) -> float:
    """The Cramér–Rao bound on one side's MTF50, % of the truth (1 σ)."""
    sn = float(np.hypot(noise, 1.0 / ((2 ** bits - 1) * np.sqrt(12.0))))
    var_sigma = sigma_information(angle_deg, sigma, aperture) * sn * sn
    f = mtf50_of(sigma, angle_deg, pixel_aperture=aperture)
    h = 1e-4 * sigma
    dfds = (mtf50_of(sigma + h, angle_deg, pixel_aperture=aperture)
            - mtf50_of(sigma - h, angle_deg, pixel_aperture=aperture)) / (2 * h)
    return 100.0 * abs(dfds) * np.sqrt(var_sigma) / f


def pooled(bounds: np.ndarray, draws: int, rng) -> dict:
    """Median, 95th percentile and expected worst of ``|N(0, s)|`` over
    edges of bounds ``s`` (%), drawn ``draws`` times."""
    e = np.abs(rng.normal(size=(draws, bounds.size)) * bounds[None, :])
    return {"n": int(bounds.size), "median": round(float(np.median(e)), 4),
            "p95": round(float(np.percentile(e, 95)), 4),
            "worst": round(float(np.median(e.max(axis=1))), 4),
            "bound_median": round(float(np.median(bounds)), 4)}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--draws", type=int, default=200, help="sets of efficient errors drawn (default 200)")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    per_edge = {}
    charts = []
    for case in sweep_cases():
        # each square's four sides share its angle; the squares cycle through the angles
        angles = [SWEEP_ANGLES[i % len(SWEEP_ANGLES)] for i in range(case.grid[0] * case.grid[1])]
        b = np.repeat([mtf50_bound_pct(a, case.sigma, case.aperture, case.noise, case.bits) for a in angles], 4)
        per_edge[case.name] = (case, b)
        charts.append({"chart": case.name, "sigma_px": case.sigma, "noise": case.noise, "bits": case.bits,
                       "pixel_aperture": case.aperture, "bound_median_pct": round(float(np.median(b)), 4),
                       "bound_max_pct": round(float(b.max()), 4)})
    groups = {"snr_100_up": lambda c: c.noise == 0 or STEP / c.noise >= 100}
    groups.update({f"noise_{n * 100:g}%": (lambda c, n=n: c.noise == n) for n in sorted({c.noise for c, _ in
                                                                                         per_edge.values()})})
    summary = {}
    for name, keep in groups.items():
        b = np.concatenate([v for c, v in per_edge.values() if keep(c)])
        summary[name] = pooled(b, args.draws, rng)
    by_sigma = {}
    for s in sorted({c.sigma for c, _ in per_edge.values()}):
        b = np.concatenate([v for c, v in per_edge.values() if c.sigma == s and (c.noise == 0 or STEP / c.noise >= 100)])
        by_sigma[f"σ {s:g} px"] = pooled(b, args.draws, rng)
    tools = {}
    rec = _harness.ROOT / "benchmarks" / "results" / "sfr_chart.json"
    if rec.is_file():
        sweep = json.loads(rec.read_text())["results"].get("sweep_summary", {})
        for tool, v in sweep.items():
            if "snr_100_up" in v:
                tools[tool] = {k: v["snr_100_up"][k] for k in ("median", "p95", "worst")}
    row = summary["snr_100_up"]
    print(f"efficient unbiased estimator, SNR ≥ 100 ({row['n']} edges): median {row['median']:.3f} %, "
          f"p95 {row['p95']:.3f} %, worst {row['worst']:.3f} %; targets {TARGETS}")
    for tool, v in tools.items():
        print(f"  {tool}: median {v['median']:.3f} %, p95 {v['p95']:.3f} %, worst {v['worst']:.3f} %")
    for k, v in by_sigma.items():
        print(f"  {k}: median {v['median']:.3f} %, p95 {v['p95']:.3f} %, worst {v['worst']:.3f} %")
    verdict = {k: row[k] <= TARGETS[k] for k in TARGETS}
    return _harness.publish("sfr_bound", {"targets": TARGETS, "summary": summary, "by_sigma": by_sigma,
                                          "tools_recorded": tools, "bound_meets_targets": verdict,
                                          "charts": charts}, args, argv)


if __name__ == "__main__":
    main()
