"""Does the correction leave flat fields alone?

A PSF that sums to 1 moves no light further than it reaches, so an optical
correction must leave the level of a flat field unchanged. This runs flat
frames (``--levels`` × four colours, camera RGB at the correction slot)
through the ``correction`` stage with each ``--model`` and reports, per
model, the largest change of a channel's mean over the frame's centre,
relative to ``max(level, 0.01)`` (so that the darkest levels, where 1 % is
far below a DN, do not dominate). A model without the residual high-pass
can change a flat 0.005 by −13 % and 0.7 by +6 %.

Two fields that are flat only on average follow, per model: a noisy black
and dark greys (``--sigma``, Gaussian, mean 0 / 0.005 / 0.02; the change of
the mean in units of σ: a correction that works on a clipped encoding
lifts the black towards the mean of a clipped Gaussian, 0.4 σ) and a fine
random texture (uniform ±50 % around grey 0.3 per pixel and channel; the
change of its mean in %: a high-pass of the residual in the √x domain
keeps √x means, and squaring back adds the residual's local variance).

``--synth DIR`` also checks that the training pairs themselves are unbiased:
the mean of each pair's input, processed by the stages after the slot
(``restoration.synth.colour.process_after_slot`` with ``gamma=False``),
against the mean of its target, per channel, over the first ``--pairs``.

Run::

    python -m benchmarks.flat_fields                                   # the packaged model
    python -m benchmarks.flat_fields --model a.int8.onnx b.onnx --synth out/synth/e9_default

Last line: one JSON object, ``{"models": {name: {"worst_percent", "at",
"table", "noisy", "texture"}}, "synth": {...}}``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import glob  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

COLOURS = ((1.0, 1.0, 1.0), (1.0, 0.3, 0.2), (0.2, 0.5, 1.0), (0.3, 1.0, 0.4))
LEVELS = (0.003, 0.01, 0.03, 0.1, 0.2, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


def flat_field_changes(model, levels=LEVELS, colours=COLOURS, size=(256, 320)) -> dict:
    """Per level and colour, the relative change (%) of each channel's mean
    over the central 80 × 80 pixels, through the correction stage."""
    h, w = size
    keys = [(lvl, col) for lvl in levels for col in colours]
    wants = [np.float32(lvl) * np.asarray(col, np.float32) for lvl, col in keys]
    means = _centre_means(model, [np.broadcast_to(v, (h, w, 3)) for v in wants], size, side=80)
    table, worst, at = {}, 0.0, None
    for (lvl, col), want, (got, _) in zip(keys, wants, means):
        change = 100 * (got - want) / np.maximum(want, 0.01)
        table[f"{lvl:g} {col}"] = [round(float(v), 3) for v in change]
        if np.abs(change).max() > worst:
            worst, at = float(np.abs(change).max()), {"level": lvl, "colour": col}
    return {"worst_percent": round(worst, 3), "at": at, "table": table}


def _centre_means(model, frames, size, side: int | None = None) -> np.ndarray:
    """Each frame (H, W, 3) through the correction stage; the per-channel
    means over its central ``side × side`` pixels (default: its central
    half), and those of the input, (n, 2, 3)."""
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction

    h, w = size
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
    stage = Correction(model=model, progress=False)
    c = ((slice(h // 4, 3 * h // 4), slice(w // 4, 3 * w // 4)) if side is None else
         (slice(h // 2 - side // 2, h // 2 + side // 2), slice(w // 2 - side // 2, w // 2 + side // 2)))
    out = []
    for f in frames:
        y = stage.process(Frame(np.array(f, np.float32), Domain.CAMERA_RGB, meta)).data
        out.append([y[c].reshape(-1, 3).mean(0), f[c].reshape(-1, 3).mean(0)])
    return np.asarray(out, np.float64)


def noisy_field_changes(model, levels=(0.0, 0.005, 0.02), sigma: float = 0.002, size=(256, 320),
                        seed: int = 0) -> dict:
    """Per level, the change of the mean of a noisy flat field (Gaussian,
    ``sigma``, negatives kept as a raw black subtraction leaves them)
    through the correction stage, in units of ``sigma``, per channel."""
    rng = np.random.default_rng(seed)
    frames = [np.float32(lvl) + np.float32(sigma) * rng.standard_normal((*size, 3), dtype=np.float32)
              for lvl in levels]
    m = _centre_means(model, frames, size)
    table = {f"{lvl:g}": [round(float(v), 3) for v in (m[i, 0] - m[i, 1]) / sigma] for i, lvl in enumerate(levels)}
    return {"sigma": sigma, "worst_sigma": round(max(abs(v) for t in table.values() for v in t), 3),
            "table": table}


def texture_mean_change(model, level: float = 0.3, size=(256, 320), seed: int = 0) -> dict:
    """The change (%) of the mean of a fine random texture (uniform in
    ``level`` ± 50 %, each pixel and channel) through the correction stage."""
    rng = np.random.default_rng(seed)
    frame = (level * (0.5 + rng.random((*size, 3), dtype=np.float32))).astype(np.float32)
    m = _centre_means(model, [frame], size)[0]
    change = 100 * (m[0] - m[1]) / m[1]
    return {"level": level, "percent": [round(float(v), 3) for v in change],
            "worst_percent": round(float(np.abs(change).max()), 3)}


def synth_mean_ratio(directory, pairs: int = 400, border: int = 16) -> dict:
    """Input (processed, linear sRGB) over target mean per channel, over the
    first ``pairs`` pairs of a synth folder, ``border`` px trimmed."""
    from modules.gamma import srgb_eotf
    from restoration.synth.colour import process_after_slot

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
    ap = _harness.parser(__doc__)
    ap.add_argument("--model", nargs="+", default=["default"], help="ONNX files (default: the packaged model)")
    ap.add_argument("--synth", help="a synth folder: also check its pairs' mean bias")
    ap.add_argument("--pairs", type=int, default=400)
    ap.add_argument("--sigma", type=float, default=0.002, help="noise of the noisy fields (default 0.002)")
    args = ap.parse_args(argv)
    result = {"models": {}}
    for m in args.model:
        r = flat_field_changes(m)
        r["noisy"] = noisy_field_changes(m, sigma=args.sigma)
        r["texture"] = texture_mean_change(m)
        result["models"][m] = r
        print(f"{m}: worst change of a flat field {r['worst_percent']:.2f} % (level {r['at']['level']}, "
              f"colour {r['at']['colour']}); of a noisy one's mean (σ {args.sigma:g}) "
              f"{r['noisy']['table']} σ; of a texture's mean {r['texture']['percent']} %")
    if args.synth:
        result["synth"] = synth_mean_ratio(args.synth, args.pairs)
        print(f"{args.synth}: processed input / target mean per channel over {result['synth']['pairs']} pairs: "
              f"median {result['synth']['median_ratio']}, mean {result['synth']['mean_ratio']}")
    return _harness.publish("flat_fields", result, args, argv)


if __name__ == "__main__":
    main()
