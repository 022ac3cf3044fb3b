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
``ours_s, ours_no_jpeg_s, rawpy_ahd_s, rawpy_linear_s`` (each ``{median,
min, max, n}``), ``ratio_vs_ahd, ratio_vs_linear`` (of the medians),
``peak_rss_mb`` (peak RSS of our pipeline alone, measured in a fresh child
process), ``runs``, ``file``, ``threads``.

The runs of the four take turns (ours, ours without JPEG, AHD, LINEAR,
then again), so that the machine's drift falls on all alike: one warm-up
of each, then the median of ``--runs`` (with the fastest and slowest run).

Usage: python -m benchmarks.pipeline [--runs 5] [--file X.dng] [--threads 2]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = _harness.ROOT
DEFAULT_FILE = ROOT.parent / "shared" / "data" / "raw" / "SYNTHETIC_phone_S6meta_5328x3000.dng"


def _setup_threads(threads: int = 2):
    """``threads`` threads everywhere, and the allocator setting `isp` itself uses."""
    import cv2  # noqa: F401  (loaded, so that the pinning reaches its pool)

    from isp.runtime.threads import tune_allocator

    _harness.pin_threads(threads)
    tune_allocator()


def run_ours(path: str, jpeg: bool = True) -> None:
    from isp import Pipeline
    from isp.io.read import read_raw

    # like for like: LibRaw has no optical correction (the packaged model's
    # cost is benchmarks/correction.py's)
    pipeline = Pipeline.default(correction={"model": "none"})
    if not jpeg:
        pipeline = pipeline.without("jpeg")
    pipeline.run(read_raw(path))


def run_rawpy(path: str, algorithm: str) -> None:
    import rawpy

    with rawpy.imread(path) as r:
        r.postprocess(demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, algorithm),
                      use_camera_wb=True, output_bps=8)


def child_peak_rss(path: str, threads: int) -> float:
    """Peak RSS (MB) of one `read + default pipeline` in a fresh process."""
    code = (f"import benchmarks.pipeline as b; b._setup_threads({threads}); b.run_ours({path!r}); "
            "import resource; print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    return float(out.stdout.strip().splitlines()[-1])


def synthesize(path: Path) -> None:
    """A 16 MP phone capture of our own when the shared file is absent."""
    from calibration.demo import make_capture
    from isp.io.dng_write import write_dng

    dn, meta, _ = make_capture(3000, 5328)
    write_dng(path, dn, meta)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--file", default=str(DEFAULT_FILE))
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    _setup_threads(args.threads)
    path = Path(args.file)
    tmp = None
    if not path.exists():
        tmp = tempfile.TemporaryDirectory()
        path = Path(tmp.name) / "synthetic_16mp.dng"
        print(f"{args.file} absent: synthesising {path}", file=sys.stderr)
        synthesize(path)
    path = str(path)

    # warm-up (imports, caches, page cache), then the four in turn, run by run
    t = _harness.interleaved({"ours": lambda: run_ours(path), "ours_no_jpeg": lambda: run_ours(path, jpeg=False),
                              "ahd": lambda: run_rawpy(path, "AHD"), "linear": lambda: run_rawpy(path, "LINEAR")},
                             runs=args.runs)
    rss = child_peak_rss(path, args.threads)
    result = {
        "ours_s": t["ours"].as_dict(4),
        "ours_no_jpeg_s": t["ours_no_jpeg"].as_dict(4),
        "rawpy_ahd_s": t["ahd"].as_dict(4),
        "rawpy_linear_s": t["linear"].as_dict(4),
        "ratio_vs_ahd": round(t["ours"].median / t["ahd"].median, 3),
        "ratio_vs_linear": round(t["ours"].median / t["linear"].median, 3),
        "peak_rss_mb": round(rss, 1),
        "runs": args.runs,
        "threads": args.threads,
        "file": Path(args.file).name,
        "synthesised": tmp is not None,
        "self_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if tmp is not None:
        tmp.cleanup()
    print(f"ours {t['ours']} s ({t['ours_no_jpeg']} s without JPEG); LibRaw AHD {t['ahd']} s, LINEAR "
          f"{t['linear']} s; ours / AHD {result['ratio_vs_ahd']}, ours / LINEAR {result['ratio_vs_linear']}; "
          f"peak RSS {result['peak_rss_mb']} MB")
    return _harness.publish("pipeline", result, args, argv)


if __name__ == "__main__":
    main()
