"""DNG opcodes against Adobe's DNG SDK: the FUSION's geometry after
OpcodeList3, each opcode's stage image against ``dng_validate``'s, and the
time ``opcode_list3`` takes.

Geometry: the GoPro FUSION capture (``gopro_FUSION_GPFR7066.dng``, a
WarpRectilinear in OpcodeList3 whose per-plane scale corrects lateral
colour) brought to the state of Adobe's stage-3 image
(``reference/adobe_dng_sdk_1.7.1/..._stage3_quarter.png``: stage 2
demosaiced, then OpcodeList3; camera RGB without white balance, no crop, no
orientation, uint16, downscaled x1/4 with ``INTER_AREA``): ``black_level``,
``lens_shading``, ``demosaic`` and ``opcode_list3`` (or not, for the figure
without the warp), x 65535, clipped, downscaled the same way. The local
shift between ours and Adobe's is estimated per channel by phase correlation
(``cv2.phaseCorrelate``, Hann window, sub-pixel) on 64 x 64 patches every
32 pixels of the quarter-scale image (8-pixel margin; patches with a
standard deviation below 50 codes skipped as textureless); the figure is
the 90th percentile of |shift| in quarter-scale pixels, per channel and
over all three. Target: <= 0.1 with the warp.

SDK parity (where ``dng_validate`` is found: ``$DNG_VALIDATE``, the PATH,
or ``$ROOT/bin``, ROOT defaulting to ``$TMPDIR/dngsdk``): small DNGs written
by the project's writer (black 0, white 65535, so stage-2 codes are the
stored values), each with one opcode in one list, read and run through
``opcode_list1``, ``black_level``, ``opcode_list2`` (and ``opcode_list3``
for the warps, on a linear DNG), against ``dng_validate -2`` / ``-3``:
the largest difference in 16-bit codes and the pixels that differ by more
than one code.

Timing: ``opcode_list3`` on the FUSION frame (9.3 MP, two planes resampled)
and a radial + tangential WarpRectilinear on a 12 MP (3000 x 4000) RGB
frame, median of ``--runs`` (one warm-up), 2 threads.

Usage: python -m benchmarks.opcode_geometry [--runs 3] [--skip-real] [--skip-sdk]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import os  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

RAW = _harness.ROOT.parent / "shared" / "data" / "raw"
REFERENCE = RAW / "reference" / "adobe_dng_sdk_1.7.1"
FUSION = "gopro_FUSION_GPFR7066"
#: patch side, step and margin (quarter-scale pixels) of the shift estimate
PATCH, STEP, MARGIN = 64, 32, 8
#: patches flatter than this (standard deviation, 16-bit codes) are skipped
MIN_STD = 50.0


def find_dng_validate() -> str | None:
    """Adobe's ``dng_validate``: ``$DNG_VALIDATE``, on the PATH, or where
    the build script puts it (``$ROOT/bin``, ROOT defaulting to
    ``$TMPDIR/dngsdk``), or a ``dngsdk/bin`` beside the repository; None
    where absent."""
    root = Path(os.environ.get("ROOT", Path(tempfile.gettempdir()) / "dngsdk"))
    return _harness.find_tool("dng_validate", "DNG_VALIDATE", root / "bin" / "dng_validate",
                              _harness.ROOT.parent / "dngsdk" / "bin" / "dng_validate")


# --------------------------------------------------------------------------
# geometry

def camera_rgb(path: Path):
    """The frame after ``black_level``, ``lens_shading`` and ``demosaic``
    (no white balance): the state OpcodeList3 applies to."""
    from isp.io.read import read_raw
    from isp.registry import create_stage

    frame = read_raw(path)
    for name in ("opcode_list1", "black_level", "opcode_list2", "lens_shading", "demosaic"):
        frame = create_stage(name)(frame)
    return frame


def quarter(rgb: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Linear camera RGB (white = 1) as Adobe's stage-3 file holds it: x
    65535, clipped, downscaled to ``shape`` (H, W) with ``INTER_AREA``;
    float32."""
    import cv2

    x = np.clip(rgb * np.float32(65535.0), 0.0, 65535.0)
    return cv2.resize(x, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def local_shifts(ours: np.ndarray, ref: np.ndarray, channel: int) -> np.ndarray:
    """(N, 4) rows (y, x, dx, dy): the shift of ``ours`` against ``ref``
    on the patches of one channel (see the module docstring), pixels."""
    import cv2

    h, w = ref.shape[:2]
    window = cv2.createHanningWindow((PATCH, PATCH), cv2.CV_32F)
    out = []
    for y in range(MARGIN, h - PATCH - MARGIN + 1, STEP):
        for x in range(MARGIN, w - PATCH - MARGIN + 1, STEP):
            a = np.ascontiguousarray(ref[y:y + PATCH, x:x + PATCH, channel], dtype=np.float32)
            if a.std() < MIN_STD:
                continue
            b = np.ascontiguousarray(ours[y:y + PATCH, x:x + PATCH, channel], dtype=np.float32)
            (dx, dy), _ = cv2.phaseCorrelate(a, b, window)
            out.append((y, x, dx, dy))
    return np.array(out, dtype=np.float64).reshape(-1, 4)


def shift_summary(ours: np.ndarray, ref: np.ndarray) -> dict:
    """p50 and p90 of |shift| per channel (R, G, B) and over all, and the
    number of patches."""
    out, mags = {}, []
    for c, name in enumerate("RGB"):
        s = local_shifts(ours, ref, c)
        mag = np.hypot(s[:, 2], s[:, 3])
        mags.append(mag)
        out[name] = {"patches": int(mag.size), "p50": round(float(np.percentile(mag, 50)), 4),
                     "p90": round(float(np.percentile(mag, 90)), 4)}
    allm = np.concatenate(mags)
    out["all"] = {"patches": int(allm.size), "p50": round(float(np.percentile(allm, 50)), 4),
                  "p90": round(float(np.percentile(allm, 90)), 4)}
    return out


def fusion_geometry(raw: Path = RAW, reference: Path = REFERENCE) -> dict:
    """The FUSION's local shift against Adobe's stage 3, with and without
    ``opcode_list3`` (see the module docstring)."""
    import cv2

    from isp.registry import create_stage

    ref = cv2.imread(str(reference / f"{FUSION}_stage3_quarter.png"), cv2.IMREAD_UNCHANGED)
    ref = np.ascontiguousarray(ref[:, :, ::-1], dtype=np.float32)   # BGR file -> RGB
    frame = camera_rgb(raw / f"{FUSION}.dng")
    warped = create_stage("opcode_list3")(frame)
    return {"file": f"{FUSION}.dng", "warp": str(warped.history[-1]),
            "with_warp": shift_summary(quarter(warped.data, ref.shape), ref),
            "without_warp": shift_summary(quarter(frame.data, ref.shape), ref)}


# --------------------------------------------------------------------------
# SDK parity

def parity_cases() -> list[tuple[str, int, object, bool]]:
    """(label, list, opcode, linear) of the parity check: one opcode of each
    kind, in the lists it is found in."""
    from isp.opcodes import (AreaSpec, DeltaPerColumn, DeltaPerRow, FixBadPixelsConstant,
                             FixBadPixelsList, FixVignetteRadial, GainMap, MapPolynomial, MapTable,
                             ScalePerColumn, ScalePerRow, WarpFisheye, WarpRectilinear,
                             WarpRectilinear2)

    rng = np.random.default_rng(7)
    points = np.concatenate([np.stack([rng.integers(0, 120, 60), rng.integers(0, 160, 60)], 1),
                             [[0, 0], [1, 1], [60, 60], [60, 61], [119, 159]]])
    rects = np.array([[10, 30, 50, 31], [70, 70, 75, 78], [100, 0, 102, 3], [0, 120, 1, 150]])
    return [
        ("FixBadPixelsConstant", 1, FixBadPixelsConstant(0, 1), False),
        ("FixBadPixelsList", 1, FixBadPixelsList(2, points, rects), False),
        ("DeltaPerRow", 1, DeltaPerRow(AreaSpec(3, 1, 110, 150, 0, 1, 2, 2),
                                       rng.normal(0, 300, 54).astype(np.float32)), False),
        ("ScalePerColumn", 2, ScalePerColumn(AreaSpec(0, 10, 100, 160, 0, 1, 2, 1),
                                             rng.uniform(0.9, 1.1, 150).astype(np.float32)),
         False),
        ("DeltaPerColumn", 2, DeltaPerColumn(AreaSpec(0, 1, 120, 159, 0, 1, 1, 3),
                                             rng.normal(0, 300, 53).astype(np.float32)), False),
        ("ScalePerRow", 2, ScalePerRow(AreaSpec(5, 0, 120, 160, 0, 1, 1, 2),
                                       rng.uniform(0.9, 1.1, 115).astype(np.float32)), False),
        ("MapTable", 1, MapTable(AreaSpec(1, 1, 119, 159, 0, 1, 2, 2),
                                 np.minimum(np.arange(65536) * 1.5, 65535).astype(np.uint16)),
         False),
        ("MapPolynomial", 1, MapPolynomial(AreaSpec(0, 0, 120, 160), (0.01, 0.9, 0.2, -0.1)),
         False),
        ("GainMap", 1, GainMap(AreaSpec(0, 1, 120, 160, 0, 1, 2, 2),
                               rng.uniform(0.8, 1.2, (5, 6, 1)), 0.25, 0.2), False),
        ("FixVignetteRadial", 1, FixVignetteRadial((0.1, 0.05, 0.0, 0.0, 0.0), 0.45, 0.55),
         False),
        ("WarpRectilinear (lateral colour)", 3, WarpRectilinear(
            ((1.0004, 0, 0, 0), (1.0, 0, 0, 0), (1.0002, 0, 0, 0)), ((0, 0),) * 3), True),
        ("WarpRectilinear (radial)", 3, WarpRectilinear(
            ((1.0, 0.02, -0.01, 0.003), (1.0003, 0.02, -0.01, 0.003),
             (0.999, 0.02, -0.01, 0.003)), ((0.0, 0.0),) * 3, 0.47, 0.53), True),
        ("WarpRectilinear (radial + tangential)", 3, WarpRectilinear(
            ((1.0, 0.02, -0.01, 0.003),), ((0.001, -0.002),), 0.47, 0.53), True),
        ("WarpRectilinear2", 3, WarpRectilinear2(
            ((1.0, 0.01, 0.02) + (0.0,) * 12,), ((0.001, 0.0005),), ((0.1, 0.9),), 0.5, 0.45),
         True),
        ("WarpFisheye", 3, WarpFisheye(((0.9, -0.05, 0.01, 0.0), (0.91, 0.0, 0.0, 0.0),
                                        (0.92, 0.01, 0.0, 0.0)), 0.45, 0.55), True),
    ]


def _texture(shape, seed: int) -> np.ndarray:
    """A smooth random texture, 16-bit codes in 10–90 % of white."""
    import cv2

    rng = np.random.default_rng(seed)
    x = cv2.GaussianBlur(rng.random(shape).astype(np.float32), (0, 0), 1.5)
    x = (x - x.min()) / (x.max() - x.min()) * 0.8 + 0.1
    return np.round(x * 65535).astype(np.uint16)


def parity(exe: str, tmp: Path, cases=None) -> list[dict]:
    """Our stage image against ``dng_validate``'s for each case of
    :func:`parity_cases`: ``{"opcode", "list", "max_code_diff",
    "pixels_over_1", "pixels_changed"}``."""
    import tifffile

    from isp import CFA, CameraMeta
    from isp.io.dng_write import write_dng
    from isp.io.read import read_raw
    from isp.registry import create_stage

    rows = []
    for k, (label, list_no, op, linear) in enumerate(cases or parity_cases()):
        data = _texture((120, 160, 3) if linear else (120, 160), k)
        if label == "FixBadPixelsConstant":      # mark pixels bad, in clusters too
            rng = np.random.default_rng(k)
            data[rng.integers(0, 120, 200), rng.integers(0, 160, 200)] = op.constant
            data[40:43, 20] = data[0, 0] = data[119, 159] = op.constant
        meta = CameraMeta(cfa=None if linear else CFA.RGGB,
                          white_level=(65535.0,) * (3 if linear else 1),
                          color_matrix_1=np.eye(3), calibration_illuminant_1=21,
                          as_shot_neutral=(1.0, 1.0, 1.0), opcodes={list_no: (op,)})
        path = write_dng(tmp / f"case{k}.dng", data, meta)
        stage = 3 if list_no == 3 else 2
        subprocess.run([exe, f"-{stage}", str(tmp / f"case{k}_sdk"), str(path)], check=True,
                       capture_output=True, timeout=120)
        sdk = tifffile.imread(str(tmp / f"case{k}_sdk.tif")).astype(np.float64)
        frame = read_raw(path)
        names = ["opcode_list1", "black_level", "opcode_list2", "lens_shading"]
        names += ["demosaic", "opcode_list3"] if stage == 3 else []
        for name in names:
            frame = create_stage(name)(frame)
        ours = np.clip(np.rint(frame.data.astype(np.float64) * 65535.0), 0, 65535)
        diff = np.abs(ours - sdk)
        rows.append({"opcode": label, "list": f"OpcodeList{list_no}",
                     "max_code_diff": int(diff.max()),
                     "pixels_over_1": int((diff > 1).sum()),
                     "pixels_changed": int((sdk != data).sum())})
    return rows


# --------------------------------------------------------------------------
# timing

def warp_12mp(runs: int):
    """Time a radial + tangential three-plane warp on a 3000 x 4000 frame."""
    from isp.opcodes import OpcodeContext, WarpRectilinear

    rng = np.random.default_rng(0)
    data = rng.random((3000, 4000, 3), dtype=np.float32)
    op = WarpRectilinear(((1.0, 0.02, -0.01, 0.003), (1.0003, 0.02, -0.01, 0.003),
                          (0.999, 0.02, -0.01, 0.003)), ((0.001, -0.002),) * 3, 0.47, 0.53)
    return _harness.measure(lambda: op.apply(data, OpcodeContext(3)), runs=runs)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-real", action="store_true", help="no FUSION geometry or timing")
    ap.add_argument("--skip-sdk", action="store_true", help="no dng_validate parity table")
    args = ap.parse_args(argv)
    results: dict = {"target_p90": 0.1}

    missing = [p for p in (RAW / f"{FUSION}.dng", REFERENCE / f"{FUSION}_stage3_quarter.png")
               if not p.exists()]
    if args.skip_real or missing:
        if missing:
            print(f"FUSION geometry skipped: {', '.join(str(p) for p in missing)} absent")
    else:
        from isp.registry import create_stage

        geo = fusion_geometry()
        results["fusion"] = geo
        print(f"{geo['file']}: {geo['warp']}")
        print("local shift against Adobe's stage 3 (quarter-scale pixels, |shift|)")
        print(f"  {'':14s} " + "  ".join(f"{c:>15s}" for c in ("R", "G", "B", "all")))
        for key in ("without_warp", "with_warp"):
            row = geo[key]
            print(f"  {key:14s} " + "  ".join(f"p50 {row[c]['p50']:.3f} p90 {row[c]['p90']:.3f}"
                                               for c in ("R", "G", "B", "all")))
        frame = camera_rgb(RAW / f"{FUSION}.dng")
        stage = create_stage("opcode_list3")
        t = _harness.measure(lambda: stage(frame), runs=args.runs)
        results["opcode_list3_fusion_s"] = t.as_dict(4)
        print(f"opcode_list3 on the FUSION ({frame.shape[1]}x{frame.shape[0]}): {t} s")

    t = warp_12mp(args.runs)
    results["warp_radial_tangential_12mp_s"] = t.as_dict(4)
    print(f"WarpRectilinear radial + tangential, 3 planes, 4000x3000: {t} s")

    exe = None if args.skip_sdk else find_dng_validate()
    if exe is None:
        if not args.skip_sdk:
            print("SDK parity skipped: dng_validate not found ($DNG_VALIDATE, PATH, or "
                  "$TMPDIR/dngsdk/bin as shared/tools/dngsdk/build_dng_validate.sh installs it)")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            rows = parity(exe, Path(tmp))
        results["sdk_parity"] = rows
        print("our stage image against dng_validate's (16-bit codes)")
        for r in rows:
            print(f"  {r['opcode']:<40s} {r['list']}  max {r['max_code_diff']:6d}  "
                  f">1: {r['pixels_over_1']:5d}  changed by the SDK: {r['pixels_changed']}")
    return _harness.publish("opcode_geometry", results, args, argv)


if __name__ == "__main__":
    main()
