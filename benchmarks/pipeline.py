"""Speed of the default pipeline against LibRaw (rawpy.postprocess), same
process, same file, 2 threads.

Ours: read (rawpy pixels + tifffile tags) + the default pipeline without a
correction model (black level, GainMap lens shading, white balance,
bilinear demosaic, luminance with BaselineExposure, dual-illuminant DNG
colour, sRGB) — ``ours_s`` includes JPEG encoding (the whole job of `isp
process`), ``ours_no_jpeg_s`` stops at the display image as rawpy does.
LibRaw: ``rawpy.imread`` + ``postprocess`` with camera white balance, 8-bit
output, AHD (its default) and LINEAR demosaic.

Prints progress, then one JSON object as its last line:
``ours_s, ours_no_jpeg_s, rawpy_ahd_s, rawpy_linear_s, ratio_vs_ahd,
ratio_vs_linear, peak_rss_mb`` (peak RSS of our pipeline alone, measured in
a fresh child process), ``runs``, ``file``, ``threads``.

Usage: python benchmarks/pipeline.py [--runs 5] [--file X.dng]
"""

from __future__ import annotations

import os

THREADS = "2"
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[var] = THREADS

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FILE = ROOT.parent / "shared" / "data" / "raw" / "SYNTHETIC_phone_S6meta_5328x3000.dng"


def _setup_threads():
    """2 threads everywhere, and the allocator setting `isp` itself uses."""
    import cv2

    from isp.runtime.threads import tune_allocator

    cv2.setNumThreads(int(THREADS))
    tune_allocator()


def run_ours(path: str, jpeg: bool = True) -> float:
    from isp import Pipeline
    from isp.io.read import read_raw

    # like for like: LibRaw has no optical correction (the packaged model's
    # cost is benchmarks/correction.py's)
    pipeline = Pipeline.default(correction={"model": "none"})
    if not jpeg:
        pipeline = pipeline.without("jpeg")
    t0 = time.perf_counter()
    out = pipeline.run(read_raw(path))
    dt = time.perf_counter() - t0
    assert out.data.size > 0
    return dt


def run_rawpy(path: str, algorithm: str) -> float:
    import rawpy

    t0 = time.perf_counter()
    with rawpy.imread(path) as r:
        rgb = r.postprocess(demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, algorithm),
                            use_camera_wb=True, output_bps=8)
    dt = time.perf_counter() - t0
    assert rgb.size > 0
    return dt


def child_peak_rss(path: str) -> float:
    """Peak RSS (MB) of one `read + default pipeline` in a fresh process."""
    code = (f"import sys; sys.path.insert(0, {str(ROOT)!r}); import benchmarks.pipeline as b; "
            f"b._setup_threads(); b.run_ours({path!r}); import resource; "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    return float(out.stdout.strip().splitlines()[-1])


def synthesize(path: Path) -> None:
    """A 16 MP phone capture of our own when the shared file is absent."""
    from calibration.demo import make_capture
    from isp.io.dng_write import write_dng

    dn, meta, _ = make_capture(3000, 5328)
    write_dng(path, dn, meta)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--file", default=str(DEFAULT_FILE))
    args = ap.parse_args()
    _setup_threads()
    path = Path(args.file)
    tmp = None
    if not path.exists():
        tmp = tempfile.TemporaryDirectory()
        path = Path(tmp.name) / "synthetic_16mp.dng"
        print(f"{args.file} absent: synthesising {path}", file=sys.stderr)
        synthesize(path)
    path = str(path)

    run_ours(path)  # warm-up: imports, caches, page cache
    run_rawpy(path, "AHD")
    times = {"ours": [], "ours_no_jpeg": [], "ahd": [], "linear": []}
    for i in range(args.runs):
        times["ours"].append(run_ours(path))
        times["ours_no_jpeg"].append(run_ours(path, jpeg=False))
        times["ahd"].append(run_rawpy(path, "AHD"))
        times["linear"].append(run_rawpy(path, "LINEAR"))
        print(f"run {i + 1}/{args.runs}: " + ", ".join(f"{k} {v[-1]:.3f}s" for k, v in times.items()),
              file=sys.stderr)
    med = {k: statistics.median(v) for k, v in times.items()}
    rss = child_peak_rss(path)
    result = {
        "ours_s": round(med["ours"], 4),
        "ours_no_jpeg_s": round(med["ours_no_jpeg"], 4),
        "rawpy_ahd_s": round(med["ahd"], 4),
        "rawpy_linear_s": round(med["linear"], 4),
        "ratio_vs_ahd": round(med["ours"] / med["ahd"], 3),
        "ratio_vs_linear": round(med["ours"] / med["linear"], 3),
        "peak_rss_mb": round(rss, 1),
        "runs": args.runs,
        "threads": int(THREADS),
        "file": Path(args.file).name,
        "self_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    print(json.dumps(result))
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
