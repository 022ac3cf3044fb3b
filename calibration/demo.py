"""``isp demo``: a synthetic phone capture, written as a DNG and processed.

The scene is known exactly, so the demo can report how well the pipeline
undid the camera: the colour error on a ColorChecker and the lens-shading
residual on a flat grey background.

The synthetic camera
--------------------
* scene: linear sRGB (D65) — grey background, a 6×4 ColorChecker, slanted
  dark squares (5°) at the centre and in the corners;
* optics: the default phone lens (US-12210142-B2-e9, the lens of the
  packaged correction model): its polychromatic PSFs on a 5 × 7 grid of
  field regions (``calibration/data/demo_lens_psf.npz``, made by the project's
  tracer: ``calibration/data/README.md``), blended bilinearly between region
  centres over the frame (:func:`calibration.simulate.capture.blur_image`); or
  ``optics="gaussian"``, a Gaussian blur of σ = 0.7 px. Relative
  illumination ``1 − 0.6 r²`` per colour (red falling a little faster:
  colour shading);
* sensor: camera RGB = ``C`` · linear sRGB for a fixed, plausible mixing
  matrix ``C``, so ColorMatrix1 (D65) = ``C`` · M(XYZ→sRGB); a GRBG mosaic;
  Poisson–Gaussian noise (NoiseProfile S = 2e-4, O = 2e-6 on 0..1 data);
  10-bit values with black 64;
* DNG: four per-CFA-phase GainMap opcodes (17×13) that undo the shading, as
  phone DNGs carry them.

The DNG names its lens (LensModel ``US-12210142-B2-e9``), so the default
pipeline's correction stage finds the packaged model through its lens
profile (:mod:`isp.profiles`). The demo processes the capture twice, with
that model and without it (``--correction none``), and a third time a capture
without blur and noise (the reference), then reports the PSNR of each to
the reference around the slanted squares and writes a before/after crop.

The demo lives in ``calibration`` because it simulates a capture (lens blur
by a PSF map, the sensor, a DNG): ``isp`` dispatches ``isp demo`` here
lazily through its command registry, so ``isp process`` never imports it.
The demo scene's constants are in :mod:`calibration.simulate.scene`.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from isp.frame import CFA
from isp.meta import CameraMeta

from calibration.simulate.scene import CAMERA_MIX, COLORCHECKER_SRGB8, XYZ_TO_SRGB, srgb_to_linear

CFA_PATTERN = CFA.GRBG
NOISE_S, NOISE_O = 2e-4, 2e-6
BLACK, WHITE = 64, 1023


def relative_illumination(h: int, w: int) -> np.ndarray:
    """(H, W, 3) falloff per colour, 1 at the centre (pixel centres)."""
    y = (np.arange(h) + 0.5 - h / 2) / (h / 2)
    x = (np.arange(w) + 0.5 - w / 2) / (w / 2)
    r2 = (x[None, :] ** 2 + y[:, None] ** 2) / 2.0  # 1 at the corners
    k = np.array([0.66, 0.60, 0.58])
    return 1.0 - k[None, None, :] * r2[:, :, None]


def chart_layout(h: int, w: int) -> list[tuple[int, int, int, int]]:
    """(top, left, bottom, right) of the 24 ColorChecker patches."""
    size = int(min(h, w) * 0.075)
    gap = size // 5
    cw, ch = 6 * size + 5 * gap, 4 * size + 3 * gap
    top, left = (h - ch) // 2, (w - cw) // 2
    return [(top + r * (size + gap), left + c * (size + gap),
             top + r * (size + gap) + size, left + c * (size + gap) + size)
            for r in range(4) for c in range(6)]


def make_scene(h: int, w: int) -> np.ndarray:
    """The demo scene in linear sRGB, (H, W, 3) float64."""
    import cv2

    scene = np.full((h, w, 3), 0.18)
    for (t, l, b, r), rgb in zip(chart_layout(h, w), COLORCHECKER_SRGB8):
        scene[t:b, l:r] = srgb_to_linear(rgb / 255.0)
    side = int(min(h, w) * 0.12)
    for cy, cx in ((0.5, 0.12), (0.5, 0.88), (0.15, 0.12), (0.15, 0.88), (0.85, 0.12), (0.85, 0.88)):
        box = cv2.boxPoints(((cx * w, cy * h), (side, side), 5.0))
        mask = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(mask, np.round(box * 16).astype(np.int32), 1, lineType=cv2.LINE_AA, shift=4)
        scene[mask.astype(bool)] = 0.02
    return scene


def gain_maps(h: int, w: int, points=(13, 17)):
    """Four per-CFA-phase GainMap opcodes undoing :func:`relative_illumination`."""
    from isp.opcodes import AreaSpec, GainMap

    pv, ph = points
    v = np.linspace(0.0, 1.0, pv)
    u = np.linspace(0.0, 1.0, ph)
    y = (v * h - h / 2) / (h / 2)
    x = (u * w - w / 2) / (w / 2)
    r2 = (x[None, :] ** 2 + y[:, None] ** 2) / 2.0
    k = np.array([0.66, 0.60, 0.58])
    ops = []
    for i in range(2):
        for j in range(2):
            c = int(CFA_PATTERN.pattern[i, j])
            gains = (1.0 / (1.0 - k[c] * r2)).astype(np.float32)[:, :, None]
            ops.append(GainMap.spanning_image(
                gains, area=AreaSpec(top=i, left=j, bottom=h, right=w, plane=0, planes=1,
                                     row_pitch=2, col_pitch=2)))
    return tuple(ops)


#: the LensModel the demo writes: the lens whose PSFs blur it, the one the packaged
#: correction model's lens profile names (``modules/models/e9_default.toml``)
DEMO_LENS = "US-12210142-B2-e9"


def demo_meta(h: int, w: int, lens: str = DEMO_LENS) -> CameraMeta:
    """Metadata of the demo camera (everything the DNG will carry); ``lens``
    is its LensModel, the identity a lens profile matches."""
    cm = CAMERA_MIX @ XYZ_TO_SRGB
    neutral = CAMERA_MIX @ np.ones(3)
    neutral = neutral / neutral[1]
    return CameraMeta(
        make="phone-isp", model="demo phone", unique_camera_model="phone-isp demo phone",
        cfa=CFA_PATTERN, black_level=np.full((1, 1, 1), float(BLACK)), white_level=(float(WHITE),),
        color_matrix_1=cm, calibration_illuminant_1=21, as_shot_neutral=tuple(neutral),
        baseline_exposure=0.0, noise_profile=((NOISE_S, NOISE_O),),
        opcodes={2: gain_maps(h, w)}, f_number=1.8, focal_length_mm=4.3, exposure_time_s=1 / 100,
        iso=100.0, lens=lens, datetime="2026:11:21 12:00:00", bits_per_sample=10,
    )


#: the demo lens's PSF map (package data; provenance in calibration/data/README.md)
DEMO_PSF = Path(__file__).parent / "data" / "demo_lens_psf.npz"
#: ``optics`` choices of :func:`make_capture`
OPTICS = ("lens", "gaussian", "none")


def lens_blur(scene: np.ndarray) -> np.ndarray:
    """``scene`` (H, W, 3) blurred by the demo lens's PSF map, its regions
    spread over the frame (bilinear blending between region centres)."""
    from calibration.simulate.capture import blur_image
    from calibration.optics.psf.map import PSFMap

    h, w = scene.shape[:2]
    return blur_image(scene, PSFMap.from_npz(DEMO_PSF), size_px=(h, w))


def make_capture(h: int = 1500, w: int = 2000, seed: int = 0, exposure: float = 0.8, *,
                 optics: str = "lens", noise: bool = True):
    """Simulate the demo capture.

    ``optics``: ``"lens"`` (the default phone lens, :func:`lens_blur`,
    written as LensModel :data:`DEMO_LENS`), ``"gaussian"`` (σ = 0.7 px) or
    ``"none"`` (no LensModel, so no lens profile matches either);
    ``noise=False`` leaves out the sensor noise (the reference capture of
    :func:`run_demo`).

    Returns
    -------
    mosaic : (H, W) uint16 DN
    meta : CameraMeta
    scene : (H, W, 3) float64 linear sRGB (the truth)
    """
    import cv2

    if h % 2 or w % 2 or h < 64 or w < 64:
        raise ValueError(f"demo size must be even and at least 64x64, got {w}x{h}")
    if optics not in OPTICS:
        raise ValueError(f"optics must be one of {', '.join(OPTICS)}; got {optics!r}")
    rng = np.random.default_rng(seed)
    scene = make_scene(h, w)
    if optics == "lens":
        blurred = lens_blur(scene)
    elif optics == "gaussian":
        blurred = cv2.GaussianBlur(scene.astype(np.float32), (0, 0), 0.7).astype(np.float64)
    else:
        blurred = scene
    cam = np.einsum("ij,hwj->hwi", CAMERA_MIX, blurred) * exposure
    cam *= relative_illumination(h, w)
    mosaic = np.empty((h, w))
    for i in range(2):
        for j in range(2):
            mosaic[i::2, j::2] = cam[i::2, j::2, int(CFA_PATTERN.pattern[i, j])]
    mosaic = np.clip(mosaic, 0.0, None)
    noisy = mosaic + rng.standard_normal(mosaic.shape) * np.sqrt(NOISE_S * mosaic + NOISE_O) if noise else mosaic
    dn = np.clip(np.round(noisy * (WHITE - BLACK) + BLACK), 0, WHITE).astype(np.uint16)
    lens = {"lens": DEMO_LENS, "gaussian": "Gaussian blur 0.7 px"}.get(optics, "")
    return dn, demo_meta(h, w, lens), scene


def square_boxes(h: int, w: int) -> dict[str, list[tuple[slice, slice]]]:
    """Windows around the slanted squares of :func:`make_scene`, by field
    zone: ``"mid-edge"`` (left and right, 0.76 of the half-width out) and
    ``"corners"`` (the four near the corners)."""
    side = int(min(h, w) * 0.12)
    half = int(side * 0.75)
    zones = {"mid-edge": [(0.5, 0.12), (0.5, 0.88)],
             "corners": [(0.15, 0.12), (0.15, 0.88), (0.85, 0.12), (0.85, 0.88)]}
    return {z: [(slice(max(0, int(cy * h) - half), int(cy * h) + half),
                 slice(max(0, int(cx * w) - half), int(cx * w) + half)) for cy, cx in c]
            for z, c in zones.items()}


def psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio of ``a`` against ``b``, dB."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(peak * peak / mse)


def _process(dng: Path, *, correction: bool):
    """(display-referred RGB before JPEG, linear RGB, the pipeline, the
    encoded output frame) of the built-in ``linear`` look, with or without
    the correction model of the capture's lens profile."""
    from isp.frame import Domain
    from isp.pipeline import Pipeline
    from isp.io.read import read_raw

    keep = {}

    def on_step(i, stage, fr, dt):
        if fr.domain is Domain.LINEAR_RGB:
            keep["linear"] = fr.data
        if fr.domain is Domain.DISPLAY_RGB:
            keep["display"] = fr.data

    # the scene-referred look: the demo scores linear RGB against the known scene
    pipeline = Pipeline.default("linear") if correction else \
        Pipeline.default("linear", correction={"model": "none"})
    out = pipeline.run(read_raw(dng), on_step=on_step)
    return keep["display"], keep["linear"], pipeline, out


def before_after_figure(path: Path, crops: list[np.ndarray], labels: list[str], zoom: int = 3) -> Path:
    """Side-by-side crops (display RGB in 0..1), each enlarged ``zoom``× by
    pixel replication and labelled, as a PNG (written atomically)."""
    import cv2

    from isp.io.files import write_bytes_atomic

    tiles = []
    for crop, label in zip(crops, labels):
        t = np.repeat(np.repeat(np.clip(crop, 0, 1), zoom, 0), zoom, 1)
        t = np.ascontiguousarray((t[..., ::-1] * 255 + 0.5).astype(np.uint8))
        (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
        cv2.rectangle(t, (0, 0), (tw + 12, th + 14), (0, 0, 0), -1)
        cv2.putText(t, label, (6, th + 6), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(t)
        tiles.append(np.full((t.shape[0], 6, 3), 255, np.uint8))
    ok, png = cv2.imencode(".png", np.concatenate(tiles[:-1], axis=1))
    write_bytes_atomic(path, png.tobytes())
    return path


def run_demo(outdir: Path, size=(1500, 2000), seed: int = 0) -> int:
    """Write ``demo.dng``, process it into ``demo.jpg`` (corrected) and
    ``demo_no_correction.jpg``, write ``demo_before_after.png`` and print
    what was measured."""
    import tempfile

    import colour

    from isp.io.dng_write import write_dng
    from isp.io.files import write_output

    h, w = size
    outdir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    dn, meta, scene = make_capture(h, w, seed)
    dng = write_dng(outdir / "demo.dng", dn, meta)
    t1 = time.perf_counter()
    after, lin, pipeline, out = _process(dng, correction=True)
    jpg = write_output(out, outdir / "demo.jpg")
    t2 = time.perf_counter()
    before, lin_nc, _, out_nc = _process(dng, correction=False)
    jpg_nc = write_output(out_nc, outdir / "demo_no_correction.jpg")
    with tempfile.TemporaryDirectory() as tmp:
        dn_ref, _, _ = make_capture(h, w, seed, optics="none", noise=False)
        ref, _, _, _ = _process(write_dng(Path(tmp) / "sharp.dng", dn_ref, meta), correction=False)

    def chart_error(lin):
        # exposure is a free scale: fit it on the neutral patches
        patches = chart_layout(h, w)
        got = np.array([lin[t + 4:b - 4, l + 4:r - 4].reshape(-1, 3).mean(0) for t, l, b, r in patches])
        want = srgb_to_linear(COLORCHECKER_SRGB8 / 255.0)
        scale = float(np.sum(got[18:] * want[18:]) / np.sum(got[18:] ** 2))
        lab_got = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.clip(got * scale, 0, None), apply_cctf_decoding=False))
        lab_want = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(want, apply_cctf_decoding=False))
        return colour.delta_E(lab_got, lab_want, method="CIE 2000")

    de, de_nc = chart_error(lin), chart_error(lin_nc)
    # lens shading is the lens_shading stage's work: read it without the optical correction, whose
    # sharpening lifts the grey next to the top-left square (inside the corner box on small frames)
    g = lin_nc[..., 1]
    corner_box = (slice(h // 40, h // 12), slice(w // 40, w // 12))
    centre_box = (slice(h * 2 // 9 - 20, h * 2 // 9 + 20), slice(w // 2 - 20, w // 2 + 20))
    corner = float(np.median(g[corner_box]))
    centre = float(np.median(g[centre_box]))
    ri = relative_illumination(h, w)[..., 1]
    uncorrected = float(np.median(ri[corner_box]) / np.median(ri[centre_box]))
    print(f"wrote {dng} ({w}x{h} GRBG, 10-bit, GainMap lens shading, NoiseProfile) in {t1 - t0:.2f} s")
    print(f"wrote {jpg} in {t2 - t1:.2f} s through: {', '.join(s.name for s in pipeline.stages)}")
    print(f"colour error on the ColorChecker: mean ΔE00 {de.mean():.2f}, max {de.max():.2f} "
          f"(without the correction: mean {de_nc.mean():.2f}, max {de_nc.max():.2f})")
    print(f"lens shading: corner / top-centre of the grey background {corner / centre:.3f} "
          f"(uncorrected {uncorrected:.3f}; ideal 1.000)")

    corr = next(s for s in pipeline.stages if s.name == "correction")
    what = corr.summary(meta)
    zones = square_boxes(h, w)
    scores = {z: (np.mean([psnr(before[b], ref[b]) for b in boxes]), np.mean([psnr(after[b], ref[b]) for b in boxes]))
              for z, boxes in zones.items()}
    side = int(min(h, w) * 0.12)  # the top-left square's upper-left corner, 0.6 of a side wide
    box = (slice(max(0, int(0.15 * h - 0.8 * side)), int(0.15 * h - 0.2 * side)),
           slice(max(0, int(0.12 * w - 0.8 * side)), int(0.12 * w - 0.2 * side)))
    fig = before_after_figure(outdir / "demo_before_after.png", [before[box], after[box], ref[box]],
                              ["no correction", "corrected", "no blur, no noise"], zoom=4)
    print(f"optical correction: model {what['model']} (profile {what.get('profile')}, {what.get('source')}, "
          f"lens {what.get('lens')}); wrote {jpg_nc} without it")
    print("  PSNR to the capture without blur and noise, around the slanted squares: "
          + ", ".join(f"{z} {b:.2f} -> {a:.2f} dB" for z, (b, a) in scores.items()))
    print(f"  before/after crop (top-left square): {fig}")
    return 0
