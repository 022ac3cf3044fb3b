"""Does the correction leave flat fields alone? (restoration issue; README, "Local means").

A PSF that sums to 1 moves no light further than it reaches, so an optical
correction must leave the level of a flat field unchanged. This runs flat
frames (``--levels`` × four colours, camera RGB at the correction slot)
through the ``correction`` stage with each ``--model`` and reports, per
model, the largest change of a channel's mean over the frame's centre,
relative to ``max(level, 0.01)`` (so that the darkest levels, where 1 % is
far below a DN, do not dominate). The packaged model without the residual
high-pass changed a flat 0.005 by −13 % and 0.7 by +6 %.

``--synth DIR`` also checks that the training pairs themselves are unbiased:
the mean of each pair's input, processed by the stages after the slot
(``restoration.synth_colour.process_after_slot`` with ``gamma=False``),
against the mean of its target, per channel, over the first ``--pairs``.

Run::

    python -m benchmarks.flat_fields                                   # the packaged model
    python -m benchmarks.flat_fields --model a.int8.onnx b.onnx --synth out/synth/e9_default

Last line: one JSON object, ``{"models": {name: {"worst_percent", "at",
"table"}}, "synth": {...}}``.
"""

from __future__ import annotations

import argparse
import glob
import json
from pathlib import Path

import numpy as np

COLOURS = ((1.0, 1.0, 1.0), (1.0, 0.3, 0.2), (0.2, 0.5, 1.0), (0.3, 1.0, 0.4))
LEVELS = (0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def flat_field_changes(model, levels=LEVELS, colours=COLOURS, size=(256, 320)) -> dict:
    """Per level and colour, the relative change (%) of each channel's mean
    over the central 80 × 80 pixels, through the correction stage."""
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction

    h, w = size
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
    stage = Correction(model=model, progress=False)
    table, worst, at = {}, 0.0, None
    for lvl in levels:
        for col in colours:
            want = np.float32(lvl) * np.asarray(col, np.float32)
            out = stage.process(Frame(np.broadcast_to(want, (h, w, 3)).copy(), Domain.CAMERA_RGB, meta)).data
            got = out[h // 2 - 40:h // 2 + 40, w // 2 - 40:w // 2 + 40].reshape(-1, 3).mean(0)
            change = 100 * (got - want) / np.maximum(want, 0.01)
            table[f"{lvl:g} {col}"] = [round(float(v), 3) for v in change]
            if np.abs(change).max() > worst:
                worst, at = float(np.abs(change).max()), {"level": lvl, "colour": col}
    return {"worst_percent": round(worst, 3), "at": at, "table": table}


def synth_mean_ratio(directory, pairs: int = 400, border: int = 16) -> dict:
    """Input (processed, linear sRGB) over target mean per channel, over the
    first ``pairs`` pairs of a synth folder, ``border`` px trimmed."""
    from modules.gamma import srgb_eotf
    from restoration.synth_colour import process_after_slot

    lum = json.loads((Path(directory) / "manifest.json").read_text())["process"]["luminance"]
    ratios = []
    for f in sorted(glob.glob(str(Path(directory) / "shard-*.npz"))):
        z = np.load(f)
        for i in range(len(z["index"])):
            if len(ratios) >= pairs:
                break
            lin = process_after_slot(z["input"][i].astype(np.float32), z["ccm"][i], float(z["exposure_ev"][i]),
                                     luma_weights=z["luma_weights"][i], tone=lum["tone"], white=lum["white"],
                                     gamma=False)
            t = srgb_eotf(z["target"][i].astype(np.float32) / 255.0)
            c = slice(border, -border)
            ratios.append(lin[c, c].reshape(-1, 3).mean(0) / t[c, c].reshape(-1, 3).mean(0))
    r = np.array(ratios)
    return {"pairs": len(r), "median_ratio": [round(float(v), 4) for v in np.median(r, 0)],
            "mean_ratio": [round(float(v), 4) for v in r.mean(0)]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--model", nargs="+", default=["default"], help="ONNX files (default: the packaged model)")
    ap.add_argument("--synth", help="a synth folder: also check its pairs' mean bias")
    ap.add_argument("--pairs", type=int, default=400)
    args = ap.parse_args(argv)
    result = {"models": {}}
    for m in args.model:
        r = flat_field_changes(m)
        result["models"][m] = r
        print(f"{m}: worst change of a flat field {r['worst_percent']:.2f} % (level {r['at']['level']}, "
              f"colour {r['at']['colour']})")
    if args.synth:
        result["synth"] = synth_mean_ratio(args.synth, args.pairs)
        print(f"{args.synth}: processed input / target mean per channel over {result['synth']['pairs']} pairs: "
              f"median {result['synth']['median_ratio']}, mean {result['synth']['mean_ratio']}")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
