"""Closing the loop on the real edge photographs of ../shared/data/edges.

Unknown cameras, unknown lenses, unknown processing: the base model is the
parametric optical MTF (:class:`calibration.loop.base.ParametricBase`:
diffraction at a fitted F-number × Gaussian aberration blur × the square
pixel aperture, pixel pitch assumed 1 µm so only λN/pitch means anything)
and the whole effect registry is tried, exactly as
``isp calib loop --lens parametric --measured FILE`` does (same loaders,
same loop). Single-edge ROI files are split along the edge into segments
(:func:`calibration.fit.measurements.load_measured`).

Encoding: JPEG and BMP files are camera output and measured as sRGB; the
8-bit TIFF ROIs as linear codes, as the reference SFR tools measured them
(``benchmarks/sfr_reference.py``). Colour files: the green channel.

Skipped, and why:

* ``baotou_CALVAL_satellite_edge.tif`` — a satellite product: a pushbroom
  line sensor's image resampled to a ground grid, 101 × 101 px with zeros
  outside the target; one short edge, neither a camera's pixel grid nor a
  lens at an F-number in front of it;
* ``mtfpy_slant.png`` — synthetic, a binary aliased edge (no optics at all);
* ``sfrmat5_ISO_12233-2023_chart_digital.jpg`` — the chart's digital file,
  not a photograph of it.

Prints a Markdown table, writes ``docs/loop_real_edges.png`` (measured SFR
against the base model before and the model with the kept effects after),
then one JSON object as its last line. Usage::

    python -m benchmarks.loop_real [--no-plot]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data" / "edges"
FIGURE = ROOT / "docs" / "loop_real_edges.png"

from calibration.loop.closure import close_loop  # noqa: E402
from calibration.fit.measurements import load_measured  # noqa: E402
from calibration.loop.base import make_base  # noqa: E402
from calibration.loop.closure import model_sfr  # noqa: E402
from isp.runtime.executor import pool_executor  # noqa: E402

# file, encoding, shortest chart edge (px)
FILES = (
    ("sfrmat3_v_edge.tif", "linear", 40),
    ("sfrmat3_v_edge_mono.tif", "linear", 40),
    ("sfrmat3_h_edge.tif", "linear", 40),
    ("sfrmat3_h_edge_mono.tif", "linear", 40),
    ("sfrmat5_Test_edge1.tif", "linear", 40),
    ("sfrmat5_Test_edge1_mono.tif", "linear", 40),
    ("sfrmat3_ISO_DSC_300a.jpg", "srgb", 40),
    ("sfrmat3_ISO_DSC_300_mono.jpg", "srgb", 40),
    # 640 × 480 with strong barrel distortion: at 40 px only the two sides of
    # one bar survive; 25 px keeps eight edges over five field regions
    ("rayxie_webcam_iso12233_original_img.bmp", "srgb", 25),
)
SKIPPED = {
    "baotou_CALVAL_satellite_edge.tif": "satellite product resampled to a ground grid, one short edge: not a camera",
    "mtfpy_slant.png": "synthetic binary aliased edge: no optics",
    "sfrmat5_ISO_12233-2023_chart_digital.jpg": "the chart's digital file, not a photograph",
}


def run(name: str, encoding: str, min_edge: float) -> dict:
    t0 = time.perf_counter()
    obs, notes = load_measured(str(DATA / name), encoding=encoding, min_edge=min_edge)
    regions = len({tuple(r) for r in obs.region})
    base = make_base("parametric", obs)
    with pool_executor(None) as ex:   # up to 2 worker processes, no progress bar
        rep = close_loop(base, obs, folds=max(2, min(3, regions)), executor=ex)
    seconds = time.perf_counter() - t0
    xb0 = rep.base_x_before
    return {
        "file": name, "encoding": encoding, "observations": len(obs), "regions": regions,
        "split": any("segments" in n and "split" in n for n in notes),
        "base_before": dict(zip(rep.base_names, map(float, xb0))),
        "base_after": dict(zip(rep.base_names, map(float, rep.base_x))),
        "effects_added": rep.effects_added, "effect_values": rep.effect_values,
        "gains": {t["effect"]: round(t["gain"], 3) for t in rep.tried if t["round"] == 1},
        "error_before": rep.error_before, "error_after": rep.error_after, "noise_floor": rep.noise_floor,
        "by_direction_after": rep.decomposition_after.get("direction", {}), "unexplained": rep.unexplained,
        "asymmetry": rep.asymmetry, "seconds": round(seconds, 2),
        "_curves": (obs, model_sfr(base, xb0, {}), model_sfr(base, rep.base_x, rep.effect_values)),
    }


def _effects_text(r: dict) -> str:
    if not r["effects_added"]:
        return "none"
    return "; ".join(f"{n} (" + ", ".join(f"{k} {v:.3g}" for k, v in r["effect_values"][n].items()) + ")"
                     for n in r["effects_added"])


def _asym_text(r: dict) -> str:
    """The LSF asymmetry left (the parametric base's LSF is symmetric):
    χ² per term and the measured A RMS in the 0.25–0.35 cycles/pixel band."""
    a = r.get("asymmetry")
    if not a:
        return "–"
    return f"{a['chi2_per_term']:.1f} (A {a['measured_rms_per_band'][2]:.3f})"


def table(rows: list[dict]) -> str:
    out = [("| file | edges (obs. / regions) | F-number, σ px after | effects added | SFRA RMS before → after "
            "| SFR MSE before → after | χ²/term before → after | noise floor | LSF asymmetry χ²/term | s |"),
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b, a = r["error_before"], r["error_after"]
        edges = f"{r['observations']} / {r['regions']}" + (" (1 edge split)" if r["split"] else "")
        out.append(f"| {r['file']} | {edges} | f/{r['base_after']['f_number']:.2f}, {r['base_after']['sigma_px']:.2f} "
                   f"| {_effects_text(r)} | {b['sfra_rms']:.4f} → {a['sfra_rms']:.4f} "
                   f"| {b['sfr_mse']:.2e} → {a['sfr_mse']:.2e} | {b['chi2_per_obs']:.1f} → {a['chi2_per_obs']:.1f} "
                   f"| {r['noise_floor']:.4f} | {_asym_text(r)} | {r['seconds']:.1f} |")
    return "\n".join(out)


def figure(rows: list[dict], path: Path) -> Path:
    """One panel per colour file (the mono twins look the same): measured
    SFR (mean, and per edge direction where both exist; grey: the range
    over observations), the base model's fit before and the model with the
    kept effects after."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from isp.io.files import write_bytes_atomic

    rows = [r for r in rows if "_mono" not in r["file"]]
    cols = 3
    nr = (len(rows) + cols) // cols                     # one spare panel for the legend
    fig, axes = plt.subplots(nr, cols, figsize=(10, 2.7 * nr), sharex=True, sharey=True)
    for ax, r in zip(axes.ravel(), rows):
        obs, before, after = r["_curves"]
        f = np.asarray(obs.freq)
        m = f <= 0.7
        meas = np.asarray(obs.sfr)[:, m]
        ax.fill_between(f[m], np.nanmin(meas, axis=0), np.nanmax(meas, axis=0), color="0.88", lw=0)
        a = np.asarray(obs.normal_deg) % 180.0
        vert = (a < 45) | (a >= 135)
        groups = [(vert, "k"), (~vert, "tab:purple")] if vert.any() and (~vert).any() else [(vert | ~vert, "k")]
        for sel, c in groups:
            ax.plot(f[m], np.nanmean(meas[sel], axis=0), color=c, lw=1.5)
            ax.plot(f[m], before[sel][:, m].mean(axis=0), color=c, lw=1.0, ls=":")
            ax.plot(f[m], after[sel][:, m].mean(axis=0), color=c, lw=1.0, ls="--")
        ax.axvline(0.5, color="0.6", lw=0.5)
        b, aft = r["error_before"], r["error_after"]
        ax.set_title(f"{r['file'].rsplit('.', 1)[0]}\n{', '.join(r['effects_added']) or 'no effect kept'}; "
                     f"SFR MSE {b['sfr_mse']:.1e} → {aft['sfr_mse']:.1e}", fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    spare = axes.ravel()[len(rows):]
    for ax in spare:
        ax.axis("off")
    line = plt.Line2D
    handles = [line([], [], color="k", lw=1.5), line([], [], color="k", lw=1.0, ls=":"),
               line([], [], color="k", lw=1.0, ls="--"), plt.Rectangle((0, 0), 1, 1, color="0.88"),
               line([], [], color="tab:purple", lw=1.5)]
    labels = ["measured SFR (mean)", "base model fit (before)", "with the kept effects (after)",
              "range over observations", "horizontal edges, where both directions exist"]
    spare[0].legend(handles, labels, loc="center", fontsize=8, frameon=False)
    for ax in axes[-1]:
        ax.set_xlabel("cycles / pixel", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("SFR", fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=96)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_bytes_atomic(path, buf.getvalue())


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--no-plot", action="store_true", help=f"do not write {FIGURE.relative_to(ROOT)}")
    args = ap.parse_args(argv)
    if not DATA.exists():
        raise SystemExit(f"loop_real: {DATA} not found (the shared data folder is needed)")
    t0 = time.perf_counter()
    rows = []
    for name, enc, min_edge in FILES:
        if (DATA / name).exists():
            rows.append(run(name, enc, min_edge))
            print(f"{name}: {rows[-1]['seconds']:.1f} s", file=sys.stderr)
    print(table(rows))
    print()
    for name, why in SKIPPED.items():
        print(f"skipped {name}: {why}")
    for r in rows:
        d = r["by_direction_after"]
        if len(d) == 2 and abs(d["vertical"] - d["horizontal"]) > 2 * r["noise_floor"]:
            print(f"{r['file']}: vertical vs horizontal edges left at {d['vertical']:+.4f} / "
                  f"{d['horizontal']:+.4f} cy/px SFRA")
    if not args.no_plot:
        print(f"wrote {figure(rows, FIGURE)}")
    total = time.perf_counter() - t0
    result = {"rows": [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows],
              "skipped": SKIPPED, "seconds": round(total, 1)}
    return _harness.publish("loop_real", result, args, argv)


if __name__ == "__main__":
    main()
