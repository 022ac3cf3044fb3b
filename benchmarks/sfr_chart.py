"""Slanted-square charts with analytic truth: per-edge MTF50 accuracy, edges
found, wall time and peak memory, ours against MTF Mapper in the same run.

Each chart is rendered exactly (:func:`calibration.sfr.synthetic.render_square_chart`:
dark squares on a light ground, Gaussian PSF of σ px, with or without the
square pixel aperture, every square at its own angle), given additive white
Gaussian noise of σₙ (fraction of the 0..1 range; the step is 0.6, so
**SNR = 0.6/σₙ**), quantised to 8 or 16 bits and written as a linear PNG
(8-bit) or TIFF (16-bit). Both tools read the file as linear codes and find
the edges themselves:

* **ours**: ``isp calib sfr FILE --chart --json OUT`` (``--method`` as given;
  each method a separate run);
* **MTF Mapper** 0.7.38 (``mtf_mapper FILE OUTDIR -q --linear``; its
  per-edge MTF50 from ``edge_mtf_values.txt``; values of 0 or ≥ 1 are its
  "not measured"). Built by ``../shared/tools/mtfmapper/build_mtf_mapper.sh``
  and found at ``$MTF_MAPPER``, on the PATH, or in ``mtfmapper/build/bin``
  beside the repository or under ``$TMPDIR``; where absent its half is
  skipped with a message.

A measured edge is matched to the nearest true square side (within a
quarter of the side's length); its error is ``MTF50 / truth − 1``, the
truth :func:`calibration.sfr.synthetic.mtf50_of` at the side's angle. Per
chart and tool: edges found and matched, median, 95th percentile and worst
of ``|error|`` (%), the mean error (the bias), and whole-process wall time
and peak RSS (one run each, after one warm-up of each tool).

A single-ROI run is timed too (``--roi-runs``, interleaved, median):
``isp calib sfr ROI.tif`` against ``mtf_mapper ROI.tif OUT -q --linear
--single-roi`` on a 150 × 100 px edge (σ 1.2 px, 5°, 16 bit).

Charts:

* ``headline``: 4000 × 3000, 9 × 13 squares (468 edges), σ 1.2 px, 5°,
  σₙ 0.3 % (SNR 200), 16 bit, with and without the pixel aperture;
* ``warped``: 2000 × 1500, 6 × 8 squares (192 edges) at 5° and 8°, σ 1.2
  px, σₙ 0.3 %, 16 bit, resampled (bicubic) through barrel distortion (the
  radius scaled by ``1 − 0.12 r²``, ``r`` over the half-diagonal), a
  perspective tilt (``1 + 0.15 y`` in the divisor, the top narrowed) and
  both with 35 % vignetting: how many sides each tool finds and measures
  where the edges curve, converge and darken (the resampling blurs, so no
  error against the truth is reported; a measured edge is matched to its
  side through the same mapping);
* ``scan``: the headline chart, point-sampled, at σ 1.1–1.3 px: the
  per-edge scatter of both tools as the MTF50 moves against MTF Mapper's
  fixed frequency grid (its SFR is sampled every 1/64 cycle/pixel and its
  MTF50 read by a quadratic through the samples around the crossing, so
  its scatter depends on where the crossing falls; σ 1.2 px puts it on a
  sample);
* ``--sweep``: 2000 × 1500, 6 × 8 squares (192 edges) at angles cycling
  through 2–40° (clear of 14.04° and 26.57°), for every σ in 0.6, 1, 1.5,
  2 px, noise 0, 0.25, 0.5, 1 % (SNR ∞, 240, 120, 60), 8 and 16 bit, with
  and without the aperture (64 charts). Pooled over SNR ≥ 100 and at
  each noise level.

* ``real``: the chart photographs of ``../shared/data/edges`` (sRGB JPEG and
  BMP: ours with ``--encoding srgb``, MTF Mapper without ``--linear``). No
  truth, so each edge either tool measured is judged by one rule: usable
  when its slant from the nearest axis is within 1–44° and its length
  gives at least one whole phase cycle (``length · tan(slant) ≥ 1`` px),
  which ISO 12233's 4× oversampled ESF needs. MTF Mapper's slant is its own
  (``edge_sfr_values.txt``) and its edge's length twice the distance from
  the edge's centroid to the corner it lists; ours are the detected angle
  and the ROI's length along the edge.

Usage::

    python -m benchmarks.sfr_chart [--sweep] [--methods accurate iso] [--no-peer]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import itertools  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from calibration.sfr.synthetic import render_square_chart  # noqa: E402

#: squares' angles in the sweep, degrees: 2–40°, clear of 14.04° and 26.57° (few distinct phases)
SWEEP_ANGLES = (2.0, 3.5, 5.0, 7.0, 9.0, 11.0, 12.5, 16.0, 19.0, 22.0, 24.5, 29.0, 32.0, 35.0, 38.0, 40.0)
SWEEP_SIGMAS = (0.6, 1.0, 1.5, 2.0)
SWEEP_NOISE = (0.0, 0.0025, 0.005, 0.01)
#: the headline chart's σ scanned (px): where the MTF50 falls against MTF Mapper's 1/64 cy/px grid
SCAN_SIGMAS = (1.1, 1.15, 1.2, 1.25, 1.3)
STEP = 0.6
#: the warped charts: barrel k1 (radius over the half-diagonal), perspective tilt, vignetting at the corners
WARPS = {"barrel": (-0.12, 0.0, 0.0), "perspective": (0.0, 0.15, 0.0),
         "barrel_perspective_vignetting": (-0.12, 0.15, 0.35)}
#: the real chart photographs measured (../shared/data/edges), all sRGB-encoded
REAL_CHARTS = ("sfrmat3_ISO_DSC_300a.jpg", "rayxie_webcam_iso12233_original_img.bmp",
               "sfrmat5_ISO_12233-2023_chart_digital.jpg")
#: a usable edge's slant from the nearest axis, degrees (our chart finder's range)
USABLE_SLANT = (1.0, 44.0)
#: issue targets at SNR ≥ 100, per-edge |ΔMTF50| %
TARGETS = {"median": 0.06, "p95": 0.25, "worst": 0.41}


@dataclass(frozen=True)
class ChartCase:
    """One chart of the benchmark."""

    name: str
    shape: tuple
    grid: tuple
    sigma: float
    angles: tuple
    noise: float
    bits: int
    aperture: bool
    warp: tuple | None = None   #: (k1, tilt, vignetting): :data:`WARPS`

    @property
    def snr(self) -> float:
        return STEP / self.noise if self.noise > 0 else float("inf")

    def as_dict(self) -> dict:
        return {"name": self.name, "size": [self.shape[1], self.shape[0]], "grid": list(self.grid),
                "sigma_px": self.sigma, "noise": self.noise, "snr": None if self.noise == 0 else round(self.snr, 1),
                "bits": self.bits, "pixel_aperture": self.aperture,
                "angles_deg": [self.angles[0]] if len(set(self.angles)) == 1 else list(self.angles),
                **({"warp": dict(zip(("k1", "tilt", "vignetting"), self.warp))} if self.warp else {})}


def headline_cases() -> list[ChartCase]:
    return [ChartCase(f"headline_{'aperture' if ap else 'point'}", (3000, 4000), (9, 13), 1.2, (5.0,), 0.003, 16, ap)
            for ap in (False, True)]


def scan_cases() -> list[ChartCase]:
    return [ChartCase(f"scan_s{sigma:g}", (3000, 4000), (9, 13), sigma, (5.0,), 0.003, 16, False)
            for sigma in SCAN_SIGMAS]


def warped_cases() -> list[ChartCase]:
    return [ChartCase(f"warped_{name}", (1500, 2000), (6, 8), 1.2, (5.0, 8.0), 0.003, 16, True, w)
            for name, w in WARPS.items()]


def centred(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """Pixel coordinates ``(x, y)`` centred on the frame and scaled by its
    half-diagonal ``r0`` (returned too): the field the warps are written in."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    r0 = float(np.hypot(w / 2.0, h / 2.0))
    return (xx - w / 2.0) / r0, (yy - h / 2.0) / r0, r0


def warp_maps(shape: tuple[int, int], k1: float, tilt: float) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel of the warped chart comes from in the rendered one:
    ``(map_x, map_y)`` (float32, for ``cv2.remap``). In :func:`centred`
    coordinates the perspective divides by ``1 + tilt·y`` and the barrel
    scales the radius by ``1 + k1·r²``."""
    h, w = shape
    x, y, r0 = centred(shape)
    cx, cy = w / 2.0, h / 2.0
    d = 1.0 + tilt * y
    xs, ys = x / d, y / d
    f = 1.0 + k1 * (xs * xs + ys * ys)
    return (xs * f * r0 + cx).astype(np.float32), (ys * f * r0 + cy).astype(np.float32)


def sweep_cases() -> list[ChartCase]:
    out = []
    for sigma, noise, bits, ap in itertools.product(SWEEP_SIGMAS, SWEEP_NOISE, (16, 8), (True, False)):
        out.append(ChartCase(f"s{sigma:g}_n{noise * 100:g}_b{bits}_{'ap' if ap else 'pt'}", (1500, 2000), (6, 8),
                             sigma, SWEEP_ANGLES, noise, bits, ap))
    return out


def write_chart(case: ChartCase, folder: Path, seed: int) -> tuple[Path, list, tuple | None]:
    """Render (and warp), add noise, quantise and write ``case``; the file,
    its true edges and, for a warped chart, the maps of :func:`warp_maps`."""
    ch = render_square_chart(case.shape, case.grid, sigma_px=case.sigma, angles_deg=case.angles,
                             pixel_aperture=case.aperture, low=0.2, high=0.8)
    img = ch.image
    maps = None
    if case.warp:
        import cv2

        k1, tilt, vignetting = case.warp
        maps = warp_maps(case.shape, k1, tilt)
        img = cv2.remap(img.astype(np.float32), *maps, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        x, y, _ = centred(case.shape)
        img = img * (1.0 - vignetting * (x * x + y * y))
    if case.noise > 0:
        img = img + np.random.default_rng(seed).normal(0.0, case.noise, img.shape)
    top = 2 ** case.bits - 1
    codes = np.round(np.clip(img, 0.0, 1.0) * top).astype(np.uint16 if case.bits == 16 else np.uint8)
    if case.bits == 16:
        import tifffile

        path = folder / f"{case.name}.tif"
        tifffile.imwrite(path, codes)
    else:
        import cv2

        path = folder / f"{case.name}.png"
        cv2.imwrite(str(path), codes)
    return path, list(ch.edges), maps


def match_sides(measured: list[tuple[float, float, float]], truth: list, maps=None) -> list[tuple[int, float]]:
    """``(side index, mtf50)`` for every measured ``(x, y, mtf50)`` that
    lies within a quarter side of a true side's midpoint (the nearest one);
    with ``maps`` (a warped chart) the position is first mapped back to the
    rendered chart."""
    centres = np.array([e.centre for e in truth])
    out = []
    for x, y, m in measured:
        if maps is not None:
            i, j = min(max(int(round(y)), 0), maps[0].shape[0] - 1), min(max(int(round(x)), 0), maps[0].shape[1] - 1)
            x, y = float(maps[0][i, j]), float(maps[1][i, j])
        d = np.hypot(centres[:, 0] - x, centres[:, 1] - y)
        i = int(np.argmin(d))
        if d[i] <= 0.25 * truth[i].length:
            out.append((i, m))
    return out



def sides_in_frame(truth: list, maps, shape: tuple[int, int], margin: int = 8, step: int = 2) -> set[int]:
    """The true sides a warped chart shows whole (their indices): five points along
    each (its ends at 0.9 of its half-length) must each be the source of an
    output pixel at least ``margin`` px inside the frame (within 1.5 sample
    steps). A side the warp pushes across the frame's border can be
    measured by no tool."""
    from scipy.spatial import cKDTree

    h, w = shape
    ys, xs = np.mgrid[margin:h - margin:step, margin:w - margin:step]
    tree = cKDTree(np.column_stack([maps[0][ys, xs].ravel(), maps[1][ys, xs].ravel()]))
    centre = {}
    for e in truth:
        centre.setdefault(e.square, []).append(e.centre)
    whole = set()
    for k, e in enumerate(truth):
        sq = np.mean(centre[e.square], axis=0)
        normal = np.subtract(e.centre, sq)
        along = np.array([-normal[1], normal[0]]) / np.hypot(*normal)
        pts = [np.add(e.centre, t * 0.5 * e.length * along) for t in (-0.9, -0.45, 0.0, 0.45, 0.9)]
        dist, _ = tree.query(pts)
        if np.all(dist <= 1.5 * step):
            whole.add(k)
    return whole


def errors_pct(pairs: list[tuple[float, float]]) -> list[float]:
    """``MTF50/truth − 1`` of each matched edge, %."""
    return [round((m / t - 1.0) * 100.0, 4) for m, t in pairs]


def error_stats(errors: list[float]) -> dict:
    """Median, p95, worst |error| and the mean signed error (the bias), % ."""
    if not errors:
        return {"n": 0}
    e = np.asarray(errors, dtype=np.float64)
    a = np.abs(e)
    return {"n": int(e.size), "median": round(float(np.median(a)), 4), "p95": round(float(np.percentile(a, 95)), 4),
            "worst": round(float(a.max()), 4), "bias": round(float(e.mean()), 4), "sd": round(float(e.std()), 4)}


def run_ours(path: Path, out: Path, method: str) -> tuple[list, dict, _harness.Child]:
    cmd = [*_harness.isp_command(), "calib", "sfr", str(path), "--chart", "--method", method, "--json", str(out)]
    child = _harness.run_child(cmd, _harness.child_env())
    d = json.loads(out.read_text())
    measured = [(e["roi"][0] + e["roi"][2] / 2.0, e["roi"][1] + e["roi"][3] / 2.0, e["mtf50"]) for e in d["edges"]
                if e["mtf50"] is not None and np.isfinite(e["mtf50"])]
    return measured, {"found": len(d["edges"]) + len(d["skipped"]), "skipped": len(d["skipped"])}, child


def find_mtf_mapper() -> str | None:
    return _harness.find_tool("mtf_mapper", "MTF_MAPPER",
                              _harness.ROOT.parent / "mtfmapper" / "build" / "bin" / "mtf_mapper",
                              Path(tempfile.gettempdir()) / "mtfmapper" / "build" / "bin" / "mtf_mapper")


def read_mtf_mapper(folder: Path) -> tuple[list, int]:
    """``(x, y, mtf50)`` of every edge MTF Mapper measured, and how many it
    listed (0 or ≥ 1 cy/px: its mark for an edge it could not measure)."""
    rows = []
    listed = 0
    for line in (folder / "edge_mtf_values.txt").read_text().splitlines():
        if not line.strip() or line.startswith("#"):
            continue
        f = line.split()
        listed += 1
        x, y, m = float(f[1]), float(f[2]), float(f[3])
        if 0.0 < m < 1.0:
            rows.append((x, y, m))
    return rows, listed


def run_mtf_mapper(exe: str, path: Path, folder: Path) -> tuple[list, dict, _harness.Child]:
    folder.mkdir(exist_ok=True)
    child = _harness.run_child([exe, str(path), str(folder), "-q", "--linear"], _harness.child_env())
    measured, listed = read_mtf_mapper(folder)
    return measured, {"found": listed, "skipped": listed - len(measured)}, child


def usable(slant_deg: float, length_px: float) -> bool:
    """Whether an edge can give ISO 12233's 4× oversampled ESF: its slant
    from the nearest axis within :data:`USABLE_SLANT` and at least one whole
    phase cycle along it (``length · tan(slant) ≥ 1`` px).

    >>> usable(5.0, 100.0), usable(0.6, 54.0), usable(2.0, 20.0)
    (True, False, False)
    """
    lo, hi = USABLE_SLANT
    return bool(lo <= slant_deg <= hi and length_px * np.tan(np.radians(slant_deg)) >= 1.0)


def axis_slant(angle_deg: float) -> float:
    """An edge's slant from the nearest image axis, degrees in [0, 45]."""
    a = float(angle_deg) % 90.0
    return min(a, 90.0 - a)


def mtf_mapper_edges(folder: Path) -> list[dict]:
    """MTF Mapper's measured edges (MTF50 in (0, 1)) with their slant (its
    own edge angle, ``edge_sfr_values.txt``) and length (twice the distance
    from the edge's centroid to the corner it lists)."""
    angle = {}
    for line in (folder / "edge_sfr_values.txt").read_text().splitlines():
        f = line.split()
        if len(f) > 4 and not line.startswith("#"):
            angle[(round(float(f[1]), 2), round(float(f[2]), 2))] = float(f[3])
    out = []
    for line in (folder / "edge_mtf_values.txt").read_text().splitlines():
        f = line.split()
        if len(f) < 6 or line.startswith("#"):
            continue
        x, y, m, cx, cy = (float(v) for v in f[1:6])
        a = angle.get((round(x, 2), round(y, 2)))
        if 0.0 < m < 1.0 and a is not None:
            out.append({"x": x, "y": y, "mtf50": m, "slant_deg": axis_slant(a), "length_px": 2.0 * np.hypot(x - cx, y - cy)})
    return out


def our_edges(report: dict) -> list[dict]:
    """Our measured edges with their slant and length (the ROI's side along the edge)."""
    out = []
    for e in report["edges"]:
        if e.get("mtf50") is None or not np.isfinite(e["mtf50"]):
            continue
        w, h = e["roi"][2], e["roi"][3]
        out.append({"x": e["roi"][0] + w / 2.0, "y": e["roi"][1] + h / 2.0, "mtf50": e["mtf50"],
                    "slant_deg": axis_slant(e["angle_deg_detected"]),
                    "length_px": float(h if e["direction"] == "vertical" else w)})
    return out


def judged(edges: list[dict]) -> dict:
    """Counts of measured and usable edges, and the slants and MTF50s of the unusable ones."""
    bad = [e for e in edges if not usable(e["slant_deg"], e["length_px"])]
    span = (lambda k: [round(min(e[k] for e in bad), 3), round(max(e[k] for e in bad), 3)] if bad else None)
    return {"measured": len(edges), "usable": len(edges) - len(bad), "unusable_slant_deg": span("slant_deg"),
            "unusable_mtf50": span("mtf50")}


def run_real(tmp: Path, peer: str | None) -> dict:
    """Both tools on the real chart photographs (:data:`REAL_CHARTS`), each
    measured edge judged by :func:`usable`."""
    from restoration.synth.defaults import DATA

    rows = {}
    for name in REAL_CHARTS:
        path = DATA / "edges" / name
        if not path.is_file():
            print(f"{path}: missing (../shared/data is needed); skipped", file=sys.stderr)
            continue
        out = tmp / f"real_{path.stem}"
        out.mkdir(exist_ok=True)
        cmd = [*_harness.isp_command(), "calib", "sfr", str(path), "--chart", "--encoding", "srgb",
               "--json", str(out / "ours.json")]
        child = _harness.run_child(cmd, _harness.child_env())
        report = json.loads((out / "ours.json").read_text())
        row = {"layout": (report["layout"] or {}).get("name"),
               "ours": {**judged(our_edges(report)), "skipped": len(report["skipped"]), "wall_s": round(child.wall_s, 3)}}
        if peer:
            (out / "mm").mkdir(exist_ok=True)
            child = _harness.run_child([peer, str(path), str(out / "mm"), "-q"], _harness.child_env())
            listed = read_mtf_mapper(out / "mm")[1]
            row["mtf_mapper"] = {**judged(mtf_mapper_edges(out / "mm")), "listed": listed,
                                 "wall_s": round(child.wall_s, 3)}
        rows[path.stem] = row
        print(f"{name}: " + "; ".join(f"{t} {v['usable']} usable of {v['measured']} measured"
                                      for t, v in row.items() if isinstance(v, dict)), file=sys.stderr)
    return rows


def run_case(case: ChartCase, tmp: Path, methods, peer: str | None, seed: int) -> dict:
    path, truth, maps = write_chart(case, tmp, seed)
    row = {"chart": case.as_dict(), "edges_true": len(truth), "tools": {}}
    whole = sides_in_frame(truth, maps, case.shape) if maps is not None else None
    if whole is not None:
        row["sides_in_frame"] = len(whole)
    tools = [(f"ours_{m}", lambda p, o, m=m: run_ours(p, o / "ours.json", m)) for m in methods]
    if peer:
        tools.append(("mtf_mapper", lambda p, o: run_mtf_mapper(peer, p, o / "mm")))
    for name, fn in tools:
        out = tmp / f"{case.name}_{name}"
        out.mkdir(exist_ok=True)
        measured, counts, child = fn(path, out)
        sides = match_sides(measured, truth, maps)
        pairs = [(m, truth[i].mtf50) for i, m in sides]
        # a warped chart's resampling blurs: its edges have no analytic truth, only their count
        errors = errors_pct(pairs) if maps is None else []
        stats = error_stats(errors) if maps is None else \
            {"mtf50_median": round(float(np.median([m for m, _ in pairs])), 4) if pairs else None}
        if whole is not None:
            stats["whole_matched"] = len(whole & {i for i, _ in sides})
        row["tools"][name] = {**counts, "matched": len(pairs), **stats,
                              "wall_s": round(child.wall_s, 3), "cpu_s": round(child.cpu_s, 3),
                              "peak_mb": round(child.peak_mb, 1), "errors_pct": errors}
    return row


def time_single_roi(tmp: Path, peer: str | None, runs: int) -> dict:
    """Whole-process seconds of one ROI measured by each tool (interleaved runs, one warm-up)."""
    import tifffile

    from calibration.sfr.synthetic import render_slanted_edge

    roi = tmp / "roi.tif"
    img = render_slanted_edge((150, 100), 5.0, 1.2, low=0.2, high=0.8)
    tifffile.imwrite(roi, np.round(img * 65535).astype(np.uint16))
    rec = _harness.Recorder(_harness.child_env(), warmup=1)
    fns = {"ours": rec.task("ours", [*_harness.isp_command(), "calib", "sfr", str(roi)])}
    if peer:
        (tmp / "mm_roi").mkdir(exist_ok=True)
        fns["mtf_mapper"] = rec.task("mtf_mapper", [peer, str(roi), str(tmp / "mm_roi"), "-q", "--linear",
                                                    "--single-roi"])
    _harness.interleaved(fns, runs=runs, warmup=1, log=False)
    return {k: rec.wall(k) for k in fns}


def pooled(rows: list[dict], tool: str, keep) -> dict:
    return error_stats([e for r in rows if keep(r) and tool in r["tools"] for e in r["tools"][tool]["errors_pct"]])


def print_rows(rows: list[dict]) -> None:
    print(f"{'chart':<22} {'tool':<14} {'found':>6} {'matched':>7} {'median %':>9} {'p95 %':>7} {'worst %':>8} "
          f"{'bias %':>7} {'wall s':>7} {'peak MB':>8}")
    for r in rows:
        for name, t in r["tools"].items():
            if not t.get("n"):
                print(f"{r['chart']['name']:<22} {name:<14} {t['found']:>6} {t['matched']:>7}")
                continue
            print(f"{r['chart']['name']:<22} {name:<14} {t['found']:>6} {t['matched']:>7} {t['median']:>9.3f} "
                  f"{t['p95']:>7.3f} {t['worst']:>8.3f} {t['bias']:>+7.3f} {t['wall_s']:>7.2f} {t['peak_mb']:>8.0f}")


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--sweep", action="store_true", help="also the 64-chart accuracy sweep")
    ap.add_argument("--methods", nargs="+", default=["accurate", "iso"], help="our SFR methods to run")
    ap.add_argument("--no-peer", action="store_true", help="leave MTF Mapper out")
    ap.add_argument("--seed", type=int, default=1, help="noise seed")
    ap.add_argument("--roi-runs", type=int, default=5, help="timed single-ROI runs of each tool (0: none)")
    args = ap.parse_args(argv)
    peer = None if args.no_peer else find_mtf_mapper()
    if peer is None and not args.no_peer:
        print("mtf_mapper not found ($MTF_MAPPER, PATH, mtfmapper/build/bin beside the repository or in $TMPDIR): "
              "its half is skipped; build it with ../shared/tools/mtfmapper/build_mtf_mapper.sh", file=sys.stderr)
    cases = headline_cases() + warped_cases() + scan_cases() + (sweep_cases() if args.sweep else [])
    rows = []
    with tempfile.TemporaryDirectory(prefix="sfr_chart_") as tmp:
        tmp = Path(tmp)
        warm = ChartCase("warmup", (300, 400), (2, 2), 1.0, (5.0,), 0.0, 16, True)
        run_case(warm, tmp, args.methods, peer, args.seed)   # bytecode compiled, caches warm
        for i, case in enumerate(cases):
            print(f"[{i + 1}/{len(cases)}] {case.name}", file=sys.stderr, flush=True)
            rows.append(run_case(case, tmp, args.methods, peer, args.seed + i))
        single = time_single_roi(tmp, peer, args.roi_runs) if args.roi_runs > 0 else None
        real = run_real(tmp, peer)
    print_rows(rows)
    if single:
        print("\nsingle ROI, whole process: " + ", ".join(f"{k} {v}" for k, v in single.items()))
    tools = sorted({t for r in rows for t in r["tools"]})
    summary = {}
    if args.sweep:
        names = {c.name for c in sweep_cases()}
        sweep = [r for r in rows if r["chart"]["name"] in names]
        for tool in tools:
            summary[tool] = {"snr_100_up": pooled(sweep, tool, lambda r: r["chart"]["noise"] <= STEP / 100),
                             **{f"noise_{n * 100:g}%": pooled(sweep, tool, lambda r, n=n: r["chart"]["noise"] == n)
                                for n in SWEEP_NOISE}}
        print("\nsweep, pooled: median / p95 / worst |ΔMTF50| %, bias %")
        for tool, s in summary.items():
            for k, v in s.items():
                if v.get("n"):
                    print(f"  {tool:<14} {k:<12} n {v['n']:>5}  {v['median']:.3f} / {v['p95']:.3f} / "
                          f"{v['worst']:.3f}  bias {v['bias']:+.3f}")
    for r in rows:   # the pooled figures are computed; the per-edge lists stay out of the record
        for t in r["tools"].values():
            t.pop("errors_pct", None)
    warped = {r["chart"]["name"].removeprefix("warped_"): {
        "sides": r["edges_true"], **{t: v["matched"] for t, v in r["tools"].items()},
        "shown whole": r["sides_in_frame"], **{f"{t} of those": v["whole_matched"] for t, v in r["tools"].items()}}
        for r in rows if r["chart"].get("warp")}
    scan = {f"σ {r['chart']['sigma_px']:g} px": {f"{t} {k}": v[k] for t, v in r["tools"].items() if v.get("n")
                                                 for k in ("median", "p95", "worst", "sd")}
            for r in rows if r["chart"]["name"].startswith("scan_")}
    result = {"mtf_mapper": peer, "methods": args.methods, "targets_snr_100_up": TARGETS, "charts": rows,
              "warped": warped, "real": real, "sigma_scan": scan, "sweep_summary": summary,
              "single_roi_s": {k: v.as_dict(3) for k, v in single.items()} if single else None}
    return _harness.publish("sfr_chart", result, args, argv)


if __name__ == "__main__":
    main()
