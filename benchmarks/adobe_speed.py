"""Speed and memory against Adobe's renderer: whole-process ``isp process``
and ``dng_validate -cs1 -tif`` on the same 12 MP real DNG, in one run.

What is timed is what a user waits for: a fresh process, from its start to
its exit, interpreter start-up and imports included. Each command runs as
a child of a small launcher process, which takes its wall time from fork
to exit and reads its CPU time (user + system) and peak resident memory
(``ru_maxrss``) from ``wait4``.

* **single file**: ``isp process FILE -o out.jpg`` (the default ``adobe``
  look; the HERO6 matches no lens profile, so no correction runs) against
  ``dng_validate -cs1 -tif out.tif FILE`` (Adobe DNG SDK 1.7.1: its final
  render, sRGB, 8-bit TIFF). ``dng_validate`` renders on one thread by
  design (the SDK's reference host); ours runs on two (OpenCV's pool, two
  JPEG bands). Paired: the two alternate run by run
  (:func:`benchmarks._harness.interleaved`), so the machine's drift falls
  on both; the ratio is of the medians;
* **with correction**: the same ``isp process`` with ``--correction
  default`` (the packaged e9 profile's model forced onto the file), in the
  same rotation, with ``--also NAME=MODEL`` other models forced alike (what
  another network costs the whole render), and the plain command once more with OpenCV's thread pool
  on one thread (``OPENCV_FOR_THREADS_NUM=1``): what that pool's threads
  cost and give, its workers waiting actively between the many short
  parallel calls of a banded pipeline;
* **batch**: ``isp batch`` of N copies of the file (symbolic links in a
  temporary folder; 2 worker processes, the default) against N
  ``dng_validate`` runs one after the other (Adobe renders one file per
  process); time per file;
* **info**: ``isp info`` on a small DNG (the LG G4's 600 × 338
  ``skia_sample_1mp.dng``, else the 512 × 384 synthetic one), and the
  interpreter's own start (``python -c pass``) for scale.

Children run with the interpreter's ``isp`` script (not a shell shim), two
threads pinned as every benchmark does, and ``PYTHONDONTWRITEBYTECODE``
removed: the warm-up run compiles the project's bytecode, as an installed
package has it. Where ``dng_validate`` is absent (``$DNG_VALIDATE``, the
PATH, ``$TMPDIR/dngsdk/bin``, ``dngsdk/bin`` beside the repository; build
it with ``../shared/tools/dngsdk/build_dng_validate.sh``) Adobe's half is
skipped with a message and ours is still measured.

Targets, on two cores: single file ≤ 1.0× Adobe's wall time; batch ≤ 0.5× Adobe's time per
file; peak ≤ 400 MB at 12 MP; ``isp info`` ≤ 0.3 s; with correction ≤ 2.0 s.

Usage: python -m benchmarks.adobe_speed [--runs 3] [--batch 8] [--file DNG] [--info-file DNG] [--also NAME=MODEL ...]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

from benchmarks.opcode_geometry import find_dng_validate  # noqa: E402

RAW = _harness.ROOT.parent / "shared" / "data" / "raw"
#: the 12 MP capture both programs render (no lens profile matches it)
DEFAULT_FILE = RAW / "gopro_HERO6_GOPR0024.dng"
#: small DNGs for ``isp info``, the first that exists
INFO_FILES = (RAW / "skia_sample_1mp.dng", RAW / "SYNTHETIC_phone_S6meta_512x384.dng")
#: the issue's targets
TARGETS = {"single_ratio": 1.0, "batch_ratio": 0.5, "peak_mb": 400.0, "info_s": 0.3, "correction_s": 2.0}


def megapixels(path: Path) -> float:
    """The raw image's size in megapixels, as the reader crops it."""
    from isp.io.read import read_raw

    h, w = read_raw(path).shape[:2]
    return h * w / 1e6


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=3, help="timed runs of each command (median reported)")
    ap.add_argument("--batch", type=int, default=8, help="files in the batch (0: skip the batch)")
    ap.add_argument("--file", type=Path, default=DEFAULT_FILE, help="the 12 MP DNG")
    ap.add_argument("--info-file", type=Path, default=None, help="the small DNG for `isp info`")
    ap.add_argument("--also", nargs="+", default=[], metavar="NAME=MODEL",
                    help="also `isp process --correction MODEL` in the same rotation (another model's cost)")
    args = ap.parse_args(argv)
    also = dict(a.split("=", 1) for a in args.also)
    if not args.file.is_file():
        print(f"skipped: {args.file} not found (the shared data is absent)", file=sys.stderr)
        return {}
    adobe = find_dng_validate()
    if adobe is None:
        print("dng_validate not found ($DNG_VALIDATE, PATH, $TMPDIR/dngsdk/bin, ../dngsdk/bin): Adobe's "
              "half is skipped; build it with ../shared/tools/dngsdk/build_dng_validate.sh", file=sys.stderr)
    isp = _harness.isp_command()
    rec = _harness.Recorder(_harness.child_env(), warmup=1)
    results: dict = {"file": args.file.name, "megapixels": round(megapixels(args.file), 2),
                     "dng_validate": adobe, "isp": " ".join(isp), "targets": TARGETS}
    with tempfile.TemporaryDirectory(prefix="adobe_speed_") as tmp:
        tmp = Path(tmp)
        ours = [*isp, "process", str(args.file), "-o", str(tmp / "ours.jpg")]
        fns = {"ours": rec.task("ours", ours)}
        if adobe:
            fns["adobe"] = rec.task("adobe", [adobe, "-cs1", "-tif", str(tmp / "adobe.tif"), str(args.file)])
        # the same with OpenCV's pool on one thread: what its worker threads' waiting costs
        fns["ours_opencv_1"] = rec.task("ours_opencv_1", ours, env={"OPENCV_FOR_THREADS_NUM": "1"})
        fns["ours_corrected"] = rec.task("ours_corrected", ours[:-1] + [str(tmp / "corr.jpg"),
                                                                        "--correction", "default"])
        for name, model in also.items():
            fns[f"also_{name}"] = rec.task(f"also_{name}", ours[:-1] + [str(tmp / f"{name}.jpg"),
                                                                         "--correction", model])
        _harness.interleaved(fns, runs=args.runs, warmup=1)
        t = {k: rec.wall(k) for k in fns}
        single = {"ours_s": t["ours"], "ours_cpu_s": rec.cpu("ours"), "ours_peak_mb": rec.peak_mb("ours"),
                  "adobe_s": t.get("adobe"), "adobe_cpu_s": rec.cpu("adobe") if adobe else None,
                  "adobe_peak_mb": rec.peak_mb("adobe") if adobe else None,
                  "ratio": t["ours"].median / t["adobe"].median if adobe else None,
                  "paired_ratios": [round(a / b, 3) for a, b in zip(t["ours"].runs, t["adobe"].runs)]
                  if adobe else None}
        single["ours_opencv_1_s"] = t["ours_opencv_1"]
        single["ours_opencv_1_cpu_s"] = rec.cpu("ours_opencv_1")
        results["single"] = single
        results["correction"] = {"ours_s": t["ours_corrected"], "ours_cpu_s": rec.cpu("ours_corrected"),
                                 "ours_peak_mb": rec.peak_mb("ours_corrected"),
                                 "also": {name: {"model": model, "ours_s": t[f"also_{name}"],
                                                 "ours_cpu_s": rec.cpu(f"also_{name}"),
                                                 "ours_peak_mb": rec.peak_mb(f"also_{name}")}
                                          for name, model in also.items()}}

        if args.batch > 0:
            folder, out = tmp / "batch", tmp / "batch_out"
            folder.mkdir()
            files = []
            for i in range(args.batch):
                link = folder / f"{i:02d}_{args.file.name}"
                link.symlink_to(args.file.resolve())
                files.append(link)
            fns = {"ours_batch": rec.task("ours_batch", [*isp, "batch", str(folder), "-o", str(out)])}
            if adobe:
                fns["adobe_batch"] = rec.task("adobe_batch", *[[adobe, "-cs1", "-tif", str(tmp / f"a{i}.tif"),
                                                                str(f)] for i, f in enumerate(files)])
            _harness.interleaved(fns, runs=args.runs, warmup=1)
            t = {k: rec.wall(k) for k in fns}
            n = args.batch
            per_ours = t["ours_batch"].map(lambda v: v / n)
            per_adobe = t["adobe_batch"].map(lambda v: v / n) if adobe else None
            results["batch"] = {"files": n, "workers": 2, "ours_total_s": t["ours_batch"],
                                "ours_per_file_s": per_ours, "adobe_total_s": t.get("adobe_batch"),
                                "adobe_per_file_s": per_adobe,
                                "ratio": per_ours.median / per_adobe.median if adobe else None}
        else:
            results["batch"] = None

    info_file = args.info_file or next((p for p in INFO_FILES if p.is_file()), None)
    if info_file is not None:
        fns = {"info": rec.task("info", [*isp, "info", str(info_file)]),
               "python": rec.task("python", [sys.executable, "-c", "pass"])}
        _harness.interleaved(fns, runs=max(args.runs, 5), warmup=1)
        t = {k: rec.wall(k) for k in fns}
        results["info"] = {"file": info_file.name, "ours_s": t["info"], "ours_cpu_s": rec.cpu("info"),
                           "ours_peak_mb": rec.peak_mb("info"), "python_start_s": t["python"]}
    else:
        results["info"] = None

    results["met"] = met(results)
    print_table(results)
    return _harness.publish("adobe_speed", results, args, argv)


def met(r: dict) -> dict:
    """Each target: met (True/False), or None where it was not measured."""
    def le(v, limit):
        return None if v is None else bool(v <= limit)

    batch, info = r.get("batch") or {}, r.get("info") or {}
    return {"single_ratio": le(r["single"]["ratio"], TARGETS["single_ratio"]),
            "batch_ratio": le(batch.get("ratio"), TARGETS["batch_ratio"]),
            "peak_mb": le(r["single"]["ours_peak_mb"], TARGETS["peak_mb"]),
            "info_s": le(info["ours_s"].median if info else None, TARGETS["info_s"]),
            "correction_s": le(r["correction"]["ours_s"].median, TARGETS["correction_s"])}


def print_table(r: dict) -> None:
    """The figures for people (seconds: median (fastest–slowest))."""
    s, c, b, i = r["single"], r["correction"], r.get("batch"), r.get("info")

    def row(what, wall, cpu=None, peak=None):
        print(f"  {what:<44s} {str(wall) if wall is not None else '–':>24s} "
              f"{str(cpu) if cpu is not None else '–':>24s} {f'{peak:.0f}' if peak else '–':>8s}")

    print(f"{r['file']} ({r['megapixels']} MP); load average at start "
          f"{', '.join(map(str, _harness.environment()['load_average_start']))}")
    print(f"  {'':<44s} {'wall s':>24s} {'cpu s':>24s} {'peak MB':>8s}")
    row("isp process -o out.jpg", s["ours_s"], s["ours_cpu_s"], s["ours_peak_mb"])
    row("dng_validate -cs1 -tif (one thread)", s["adobe_s"], s["adobe_cpu_s"], s["adobe_peak_mb"])
    row("isp process, OPENCV_FOR_THREADS_NUM=1", s["ours_opencv_1_s"], s["ours_opencv_1_cpu_s"])
    row("isp process --correction default", c["ours_s"], c["ours_cpu_s"], c["ours_peak_mb"])
    for name, a in c.get("also", {}).items():
        row(f"isp process --correction {name}", a["ours_s"], a["ours_cpu_s"], a["ours_peak_mb"])
    if b:
        row(f"isp batch, {b['files']} files: per file", b["ours_per_file_s"])
        row(f"dng_validate x {b['files']}: per file", b["adobe_per_file_s"])
    if i:
        row(f"isp info {i['file']}", i["ours_s"], i["ours_cpu_s"], i["ours_peak_mb"])
        row("python -c pass", i["python_start_s"])
    if s["ratio"] is not None:
        print(f"  single file: ours / Adobe {s['ratio']:.2f} (paired runs: "
              f"{', '.join(f'{v:.2f}' for v in s['paired_ratios'])})")
    if b and b["ratio"] is not None:
        print(f"  batch: ours per file / Adobe per file {b['ratio']:.2f}")
    for k, ok in r["met"].items():
        print(f"  target {k} <= {TARGETS[k]:g}: {'–' if ok is None else 'met' if ok else 'NOT met'}")


if __name__ == "__main__":
    main()
