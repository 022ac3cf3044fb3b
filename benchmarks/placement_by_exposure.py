"""Where does the sRGB → sRGB placement win? Its gain over the in-pipeline
model, split by the pairs' exposure and field radius (the ablations of
``benchmarks/ablations.py``).

The training pairs are compressed by ``exposure_ev`` (0–2 EV, the paper's
luminosity compression) that the luminance stage after the slot brings back
up. A model in the pipeline sees the compressed camera RGB; one at the end
of the pipeline sees the image as displayed. If the sRGB placement's lead
grows with ``exposure_ev``, what it has over ours is the exposure its input
is normalised to, not the placement as such.

For every ``--step``-th pair of a synth folder (256² crops), the sRGB PSNR
gain over no correction of each ablation model (``--models NAME:PLACEMENT``
under ``--ablations``), and the difference per exposure bin and per field
radius bin.

Run::

    python -m benchmarks.placement_by_exposure                      # the ablations64 entries
    python -m benchmarks.placement_by_exposure --synth out/synth/e9_lenses9 --step 4

Last line: one JSON object, ``{"pairs", "by_exposure": [...], "by_radius":
[...], "correlation"}``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

EV_BINS = ((0.0, 0.7), (0.7, 1.4), (1.4, 2.01))
RADIUS_BINS = ((0.0, 0.35), (0.35, 0.7), (0.7, 1.5))


def pair_gains(synth, models: dict, step: int = 4, size: int = 256) -> np.ndarray:
    """Per pair: ``exposure_ev``, the field radius of its centre, and each
    model's PSNR gain (dB) over no correction, rows in the order of
    ``models`` (name → (torch model, placement))."""
    import torch

    from restoration.train.dataset import SynthPairs
    from restoration.train.trainer import predict_srgb, process_batch, psnr_db

    pairs = SynthPairs(synth)
    rows = []
    for i in range(0, len(pairs), step):
        it = pairs[i]
        x = torch.from_numpy(np.concatenate([it["input"].transpose(2, 0, 1), it["fov"]])[None])[..., :size, :size]
        y = torch.from_numpy(it["target"].transpose(2, 0, 1)[None])[..., :size, :size]
        meta = [{"ccm": it["ccm"], "exposure_ev": float(it["exposure_ev"]), "luma_weights": it["luma_weights"],
                 "tone": pairs.tone, "white": pairs.white}]
        with torch.no_grad():
            base = psnr_db(process_batch(x[:, :3], meta), y)
            gains = [psnr_db(predict_srgb(m, x, meta, pl), y) - base for m, pl in models.values()]
        radius = float(np.hypot(*it["fov"][:, size // 2, size // 2]))
        rows.append([float(it["exposure_ev"]), radius, *gains])
    return np.asarray(rows)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--synth", default="out/synth/e9_lenses9",
                    help="pairs to score (default: the nine-camera set, whose lenses no entry trained on)")
    ap.add_argument("--ablations", default="out/ablations64", help="folder of the ablation entries")
    ap.add_argument("--models", nargs="+", default=["linear_highpass:pipeline", "srgb_highpass:srgb"],
                    help="NAME:PLACEMENT, the first the reference (default: ours, then sRGB → sRGB)")
    ap.add_argument("--step", type=int, default=4, help="every STEP-th pair (default 4)")
    args = ap.parse_args(argv)
    import torch  # noqa: F401  (loaded first, so that the pinning reaches its pool)

    from restoration.nn.checkpoint import load_model

    _harness.pin_threads(2)
    models = {}
    for spec in args.models:
        name, placement = spec.split(":")
        m = load_model(Path(args.ablations) / name / "model.pt")
        models[name] = ((m[0] if isinstance(m, tuple) else m).eval(), placement)
    a = pair_gains(args.synth, models, args.step)
    names = list(models)
    ref, other = names[0], names[-1]
    diff = a[:, 1 + len(names)] - a[:, 2]   # the last model's gain minus the reference's

    def rows(col, bins):
        out = []
        for lo, hi in bins:
            s = (a[:, col] >= lo) & (a[:, col] < hi)
            out.append({"range": [lo, hi], "pairs": int(s.sum()),
                        **{f"gain_{n}": round(float(a[s, 2 + k].mean()), 3) for k, n in enumerate(names)},
                        f"{other}_minus_{ref}": round(float(diff[s].mean()), 3)})
        return out

    result = {"pairs": len(a), "synth": args.synth, "models": args.models,
              "by_exposure": rows(0, EV_BINS), "by_radius": rows(1, RADIUS_BINS),
              "correlation": round(float(np.corrcoef(a[:, 0], diff)[0, 1]), 3)}
    for key, label in (("by_exposure", "exposure EV"), ("by_radius", "field radius")):
        for r in result[key]:
            print(f"{label} {r['range'][0]:g}–{r['range'][1]:g} ({r['pairs']} pairs): "
                  + ", ".join(f"{n} {r[f'gain_{n}']:+.3f} dB" for n in names)
                  + f"; {other} − {ref} {r[f'{other}_minus_{ref}']:+.3f} dB")
    print(f"correlation of the exposure with {other} − {ref}: {result['correlation']:+.3f}")
    return _harness.publish("placement_by_exposure", result, args, argv)


if __name__ == "__main__":
    main()
