"""Our e-SFR beside the reference tools on the real edges of ../shared/data/edges.

For every image with a JSON in ``edges/reference/`` (sfrmat3, sfrmat5 and
MTF Mapper curves on the whole image as ROI), measure the SFR with our code
(ISO mode, sfrmat5's Tukey window, edge-fit order 5 as sfrmat5 was run —
and order 1) and compare: MTF50, SFRA to Nyquist, and the RMS difference of
the curves up to Nyquist on the reference's frequency axis.

The reference tools are not run here (sfrmat is MATLAB code, MTF Mapper
a C++ program with no Python package): their curves are the ones they
computed on these images, stored in ``edges/reference/`` (one JSON per
image: frequency axis, SFR, MTF50 and SFRA of each tool).

Prints a Markdown table, then one JSON object as its last line. Usage::

    python -m benchmarks.sfr_reference
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data" / "edges"

from calibration.sfr.esfr import measure_sfr  # noqa: E402

TOOLS = ("sfrmat3", "sfrmat5", "mtf_mapper_linear")


def compare(image: Path, ref: dict) -> dict:
    import tifffile

    img = tifffile.imread(image)
    out = {"image": image.name}
    for order in (5, 1):
        r = measure_sfr(img, edge_fit_order=order, method="iso")
        row = {"mtf50": r.mtf50, "sfra": r.sfra}
        for tool in TOOLS:
            t = ref[tool]
            f = np.asarray(t["freq_cy_per_px"])
            keep = f <= 0.5
            ours = np.interp(f[keep], r.freq, r.sfr)
            row[tool] = {"mtf50": t["mtf50"], "d_mtf50_pct": 100 * (r.mtf50 / t["mtf50"] - 1),
                         "sfra": t["sfra_to_nyquist"], "d_sfra_pct": 100 * (r.sfra / t["sfra_to_nyquist"] - 1),
                         "rms_to_nyquist": float(np.sqrt(np.mean((ours - np.asarray(t["sfr"])[keep]) ** 2)))}
        out[f"order{order}"] = row
    return out


def main(argv=None) -> list:
    args = _harness.parser(__doc__).parse_args(argv)
    if not DATA.exists():
        raise SystemExit(f"sfr_reference: {DATA} not found (the shared data folder is needed)")
    rows = []
    for ref_file in sorted((DATA / "reference").glob("*.json")):
        image = DATA / (ref_file.stem + ".tif")
        if image.exists():
            rows.append(compare(image, json.loads(ref_file.read_text())))
    print("| edge | tool | tool MTF50 | ours (order 5) | Δ MTF50 | Δ SFRA | SFR RMS diff to Nyquist |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        o = row["order5"]
        for tool in TOOLS:
            t = o[tool]
            print(f"| {row['image']} | {tool} | {t['mtf50']:.4f} | {o['mtf50']:.4f} | {t['d_mtf50_pct']:+.2f} % | "
                  f"{t['d_sfra_pct']:+.2f} % | {t['rms_to_nyquist']:.4f} |")
    return _harness.publish("sfr_reference", rows, args, argv)


if __name__ == "__main__":
    main()
