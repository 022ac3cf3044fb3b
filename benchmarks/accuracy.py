"""Accuracy figures of the README, measured against independent references.

* lens shading: black level + GainMap correction of the synthetic S6 capture
  against its unshaded truth (mean |relative error| of 32×32 block means,
  clipped pixels left out), for both GainMap sampling conventions and none;
* whole images against LibRaw (``rawpy.postprocess``, matched settings) on
  every Bayer DNG of ``../shared/data/raw``: mean CIEDE2000, with LibRaw's
  own matrix ("same matrix") and with our DNG-spec colour;
* demosaic: CPSNR (dB) of each method on kodim19 (mosaicked, all four CFA
  phases averaged, 8-px border excluded).

The peer, LibRaw, runs in the same process on the same files. Prints a
summary, then one JSON object as its last line. Usage::

    python -m benchmarks.accuracy
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data"


def shading_errors() -> dict:
    from isp import Pipeline
    from isp.io.read import read_raw

    f = read_raw(DATA / "raw" / "SYNTHETIC_phone_S6meta_512x384.dng")
    truth = np.load(DATA / "raw" / "SYNTHETIC_phone_S6meta_512x384_truth_unshaded.npy")
    valid = f.data < f.meta.white_level[0]

    def err(out, b=32):
        h, w = truth.shape

        def blocks(a):
            return (a * valid)[:h // b * b, :w // b * b].reshape(h // b, b, w // b, b).sum((1, 3))
        return float(np.mean(np.abs(blocks(out) - blocks(truth)) / blocks(truth)))

    out = {}
    for label, names, params in (("none", ["black_level"], {}),
                                 ("dng", ["black_level", "lens_shading"], {}),
                                 ("cell_centred", ["black_level", "lens_shading"],
                                  {"lens_shading": {"sampling": "cell_centred"}})):
        out[label] = round(err(Pipeline.from_names(names, params).run(f).data), 5)
    return out


def rawpy_delta_e() -> dict:
    import colour
    import rawpy

    from isp import Pipeline
    from isp.io.read import read_raw

    out = {}
    for name in ("tinydng_colorchart.dng", "imageio_Blackmagic.dng",
                 "SYNTHETIC_phone_S6meta_512x384.dng", "SYNTHETIC_phone_S6meta_5328x3000.dng"):
        path = DATA / "raw" / name
        with rawpy.imread(str(path)) as r:
            ref = r.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR, use_camera_wb=True,
                                output_color=rawpy.ColorSpace.sRGB, no_auto_bright=True,
                                adjust_maximum_thr=0.0, gamma=(2.4, 12.92), output_bps=16, user_flip=0,
                                highlight_mode=rawpy.HighlightMode.Clip).astype(np.float32) / 65535
            rgb_cam = r.color_matrix[:, :3].copy()
        f = read_raw(path)
        oy, ox = f.meta.origin
        h, w = f.shape[:2]
        if ref.shape[:2] != (h, w):
            ref = ref[oy:oy + h, ox:ox + w]
        step = 3 if h * w < 4e6 else 9
        row = {}
        for label, ccm in (("same_matrix", {"matrix": tuple(rgb_cam.ravel())}), ("dng_colour", {})):
            p = Pipeline.from_names(["black_level", "white_balance", "demosaic", "ccm", "gamma"],
                                    {"ccm": ccm, "demosaic": {"method": "bilinear"}})
            o = p.run(f).data

            def lab(x):
                return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(x[4:-4:step, 4:-4:step]))
            row[label] = round(float(colour.delta_E(lab(o), lab(ref), method="CIE 2000").mean()), 4)
        out[name] = row
    return out


def demosaic_cpsnr() -> dict:
    import cv2

    from isp import CFA
    from modules.demosaic import METHODS

    img = cv2.imread(str(DATA / "latent" / "Kodak24" / "kodim19.png"))[..., ::-1].astype(np.float32) / 255
    out = {}
    for method, fn in METHODS.items():
        vals = []
        for cfa in CFA:
            mosaic = np.zeros(img.shape[:2], np.float32)
            for i in range(2):
                for j in range(2):
                    mosaic[i::2, j::2] = img[i::2, j::2, cfa.pattern[i, j]]
            rgb = fn(mosaic, cfa)
            mse = np.mean((np.clip(rgb, 0, 1)[8:-8, 8:-8] - img[8:-8, 8:-8]) ** 2)
            vals.append(10 * np.log10(1 / mse))
        out[method] = round(float(np.mean(vals)), 2)
    return out


def main(argv=None) -> dict:
    args = _harness.parser(__doc__).parse_args(argv)
    if not DATA.exists():
        raise SystemExit(f"accuracy: {DATA} not found (the shared data folder is needed)")
    result = {"lens_shading_block_rel_error": shading_errors(),
              "delta_e00_vs_rawpy": rawpy_delta_e(),
              "demosaic_cpsnr_kodim19_db": demosaic_cpsnr()}
    print(f"lens shading, block relative error: {result['lens_shading_block_rel_error']}")
    for name, row in result["delta_e00_vs_rawpy"].items():
        print(f"mean CIEDE2000 against LibRaw, {name}: {row}")
    print(f"demosaic CPSNR on kodim19 (dB): {result['demosaic_cpsnr_kodim19_db']}")
    return _harness.publish("accuracy", result, args, argv)


if __name__ == "__main__":
    main()
