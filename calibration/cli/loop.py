"""``isp calib loop``: close the loop on a measurement from the command line.

``isp calib loop --lens LENS --measured MEAS -o REPORT_DIR`` turns the
measurement into :class:`calibration.fit.observations.Observations`, builds the
base model (:mod:`calibration.loop.base`), runs
:func:`calibration.loop.closure.close_loop` and writes its report
(:func:`calibration.loop.closure.write_report`) plus a figure of the measured and
modelled SFR curves.

The measurement (``MEAS``) is one of

* a capture: a raw file (DNG, ...; edges found on the 2×2-block average and
  measured on the Bayer mosaic per colour) or an image (PNG/TIFF/JPEG/BMP,
  measured as linear codes unless ``--encoding srgb``). A chart is searched
  for slanted edges (:mod:`calibration.sfr.chart`); an image where none is
  found is taken as one slanted edge filling the frame (the ISO 12233 ROI
  files);
* the JSON of ``isp calib sfr`` (one ROI or ``--chart``);
* an ``sfr-observations/v1`` JSON (:meth:`Observations.save`).

Sensor geometry: a raw file gives its own size and, where its metadata
holds it, the pixel pitch; an image of an unknown camera is taken as the
full field (optical centre at the image centre) at ``--pixel-um``
(default 1 µm). With a parametric base only λN/pitch is identifiable, so
the fitted F-number is at that assumed pitch.

Few edges. The loop ranks effects by K-fold cross-validation over *field
regions* and fits the noise law σ ∝ noise/step over the observations
(:mod:`calibration.loop.closure`), so it needs observations in at least three
regions. A capture with fewer than three measurable edges (a single-edge
ROI file) has each edge split along its length into segments of at least
:data:`MIN_SEGMENT` lines (up to :data:`MAX_SEGMENTS` per edge), each
measured on its own. Why segments rather than cross-validating over
frequency bands or falling back to AIC alone: the segments are independent
noise realisations of the same optics, so a held-out segment tests exactly
what the loop must decide — whether an effect explains structure that
repeats beyond the noise — and the noise law gets ≥ 3 points from the data
itself. Bands are not independent (one blur parameter moves all four, and
the effects are defined by their shape across bands: holding a band out
asks the effect to extrapolate, not to explain), and AIC on one edge
would need the noise σ from the same single measurement. The price: each
segment is noisier than the whole edge (the noise floor rises ≈ √K), and
field-dependent effects are fitted over a "field" that is only the ROI; the
cross-validation keeps them out unless they explain held-out segments.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from isp.errors import IspError

MIN_SEGMENT = 64        # lines along the edge per segment (≥ 6 phase cycles at 5°)
MAX_SEGMENTS = 4
MIN_REGIONS = 3
DEFAULT_PIXEL_UM = 1.0
CHANNELS = {"r": "R", "g": "G", "b": "B", "l": "L", "luminance": "L", "y": "L", "all": "all"}


def _channels(channel: str | None, kind: str, colour: bool, path: str, notes: list) -> list[str]:
    """The colours to measure: R, G, B ("all": the three), L (luminance of
    an RGB image); a grey image has L only."""
    c = CHANNELS.get((channel or "G").strip().lower())
    if c is None:
        raise IspError(f"--channel {channel!r}: valid: R, G, B, L (luminance of an RGB image), all")
    if kind == "raw" and c == "L":
        raise IspError(f"{path}: --channel L is for RGB images; a raw file has R, G, B (or all)")
    if kind != "raw" and not colour:
        if channel is not None and c != "L":
            notes.append(f"grey image: --channel {channel} ignored")
        return ["L"]
    return ["R", "G", "B"] if c == "all" else [c]

EPILOG = """\
examples:
  isp calib loop --lens parametric --measured edge.tif --encoding linear
  isp calib loop --lens parametric --measured photo.jpg --encoding srgb --channel all -o photo_loop/
  isp calib loop --lens e9.json --measured capture.dng -o dev3_loop/ --max-effects 2
  isp calib sfr chart.png --chart --json chart.json && isp calib loop --lens parametric --measured chart.json
  isp calib loop --lens parametric --measured chart.png --effects sharpening,focus_shift,veiling_glare

what it does:
  fits the base model (a lens and its perturbations, or a parametric optical
  MTF: diffraction at F/N x Gaussian aberration blur x pixel aperture),
  estimates the noise floor from the data, tries every effect of the
  registry (sensor tilt, focus shift, field curvature, crosstalk, lateral
  colour, sharpening, glare; `--effects` to choose) by cross-validation over
  field regions, keeps the best while it explains held-out data, and writes
  REPORT_DIR/report.json, report.md, residual_maps.png and sfr_curves.png.
  A single-edge image is split along the edge into segments (see
  `calibration/cli/loop.py`).
"""


# -- measurements -> observations ------------------------------------------------------------

def _sensor(width: int, height: int, pixel_um: float | None):
    from calibration.optics.lens import Sensor

    return Sensor(pixel_pitch_um=float(pixel_um or DEFAULT_PIXEL_UM), width_px=int(width), height_px=int(height))


def _concat(parts: list, source: str, meta: dict):
    """One Observations from several with the same sensor and frequency grid."""
    from calibration.fit.observations import Observations

    keys = ("x_px", "y_px", "normal_deg", "channel", "orientation", "sfra", "sfra_std", "noise", "step")
    kw = {k: np.concatenate([np.asarray(getattr(o, k)) for o in parts]) for k in keys}
    rois = [o.roi for o in parts]
    roi = np.concatenate(rois) if all(r is not None for r in rois) else None
    odd = all(o.odd is not None for o in parts)
    return Observations(**kw, freq=parts[0].freq, sfr=np.concatenate([o.sfr for o in parts]),
                        sensor=parts[0].sensor, roi=roi, grid=parts[0].grid, source=source, meta=meta,
                        odd=np.concatenate([o.odd for o in parts]) if odd else None,
                        odd_std=np.concatenate([o.odd_std for o in parts]) if odd else None)


def _segments(roi, n: int) -> list:
    """``roi`` (an EdgeROI) cut into ``n`` equal pieces along its edge."""
    from calibration.sfr.chart import EdgeROI

    out = []
    for i in range(n):
        if roi.direction == "vertical":        # the edge runs down the rows
            y0, y1 = roi.y + roi.h * i // n, roi.y + roi.h * (i + 1) // n
            out.append(EdgeROI(roi.x, y0, roi.w, y1 - y0, roi.angle_deg, roi.direction, roi.radius,
                               roi.field_angle_deg, roi.orientation, roi.shape))
        else:
            x0, x1 = roi.x + roi.w * i // n, roi.x + roi.w * (i + 1) // n
            out.append(EdgeROI(x0, roi.y, x1 - x0, roi.h, roi.angle_deg, roi.direction, roi.radius,
                               roi.field_angle_deg, roi.orientation, roi.shape))
    return out


def _placed(roi, w: int, h: int):
    """``roi`` with its field position and orientation recomputed for where
    it lies (segments of one edge lie at different radii)."""
    from calibration.sfr.chart import EdgeROI, classify_orientation, field_position

    cx, cy = roi.centre
    radius, fang = field_position(cx, cy, (w / 2.0, h / 2.0), 0.5 * math.hypot(w, h))
    t = math.radians(roi.angle_deg)
    d = (math.sin(t), math.cos(t)) if roi.direction == "vertical" else (math.cos(t), math.sin(t))
    return EdgeROI(roi.x, roi.y, roi.w, roi.h, roi.angle_deg, roi.direction, radius, fang,
                   classify_orientation(d[0], d[1], radius, fang), roi.shape)


def _whole_frame_roi(measure, w: int, h: int):
    """The whole image as one edge ROI (an ISO 12233 ROI file), or None."""
    from calibration.sfr.esfr import SfrError
    from calibration.sfr.chart import EdgeROI

    try:
        r = measure((0, 0, w, h))
    except SfrError:
        return None
    return _placed(EdgeROI(0, 0, w, h, r.angle_deg, r.orientation, 0.0, 0.0, "axial", 0), w, h)


def _edge_place(direction: str, fit, box, w: int, h: int) -> tuple:
    """(x_px, y_px, normal_deg, orientation) of an edge measured in ``box``
    (x, y, w, h) with linear fit ``fit`` (:attr:`SfrResult.edge_fit_linear`,
    image coordinates). The observation sits where the edge crosses the
    middle of its ROI, not at the ROI's centre: segments of one edge then
    differ in x and y as the edge does."""
    from calibration.sfr.chart import classify_orientation, field_position

    c0, c1 = float(fit[0]), float(fit[1])
    bx, by, bw, bh = (float(v) for v in box)
    if direction == "vertical":                   # x = c0 + c1·y
        y = by + bh / 2.0 - 0.5
        x = c0 + c1 * y
        d = (c1, 1.0)
    else:                                         # y = c0 + c1·x
        x = bx + bw / 2.0 - 0.5
        y = c0 + c1 * x
        d = (1.0, c1)
    normal = math.degrees(math.atan2(d[0], -d[1])) % 180.0
    radius, fang = field_position(x + 0.5, y + 0.5, (w / 2.0, h / 2.0), 0.5 * math.hypot(w, h))
    return x, y, normal, classify_orientation(d[0], d[1], radius, fang)


def _edge_item(roi, r, w: int, h: int) -> tuple:
    """(x_px, y_px, normal_deg, orientation, r) for Observations.from_sfr_results."""
    return (*_edge_place(r.orientation, r.edge_fit_linear, (roi.x, roi.y, roi.w, roi.h), w, h), r)


def _measure_rois(rois, measure, progress: bool) -> tuple[list, list]:
    from calibration.sfr.chart import measure_rois

    return measure_rois(rois, measure, progress=progress and len(rois) > 8)


def observations_from_capture(img, kind: str, meta=None, *, path: str = "", channel: str | None = None,
                              encoding: str = "linear", pixel_um: float | None = None, method: str = "iso",
                              min_edge: float = 40.0, progress: bool = False, bootstrap: int = 0):
    """Observations measured on a capture, and notes on how.

    Parameters
    ----------
    img : (H, W) or (H, W, 3) ndarray
        An image (codes) or, with ``kind == "raw"``, a linear Bayer mosaic
        (black level removed), as :func:`calibration.cli.main.load_image` returns.
    kind : {"image", "raw"}
    meta : CameraMeta, optional
        Raw files: the CFA and, where known, the pixel pitch.
    channel : {"R", "G", "B", "L", "all"}, optional
        Colour measured ("L": luminance of an RGB image; "all": R, G and B
        each). Default G for raw files and RGB images.
    encoding : {"linear", "srgb"}
        How an image's codes relate to light.
    pixel_um : float, optional
        Pixel pitch, µm (default: the raw file's, else 1 µm).
    min_edge : float
        Shortest polygon side taken as an edge, pixels
        (:func:`calibration.sfr.chart.find_edges`).
    bootstrap : int
        Residual-bootstrap replicas per edge (:func:`calibration.sfr.esfr.measure_sfr`):
        each observation's ``sfra_std`` is its own measured spread instead
        of the 0.002 cycles/pixel default, so an edge whose measurement is
        unstable weighs what it is worth in a fit. 0: the default σ.

    Returns
    -------
    (Observations, list of str)
    """
    from calibration.fit.observations import GRID, Observations
    from calibration.sfr.esfr import measure_sfr, measure_sfr_bayer
    from calibration.sfr.chart import EdgeROI, find_edges

    h, w = img.shape[:2]
    notes = []
    colour = img.ndim == 3
    # seeded: the same capture measures to the same σ
    boot = {"bootstrap": int(bootstrap), "rng": 0} if bootstrap else {}
    chans = _channels(channel, kind, colour, path, notes)
    if kind == "raw":
        pixel_um = pixel_um or getattr(meta, "pixel_pitch_um", None)
        mosaic = np.asarray(img, dtype=np.float64)
        half = mosaic[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
        rois = [EdgeROI(2 * r.x, 2 * r.y, 2 * r.w, 2 * r.h, r.angle_deg, r.direction, r.radius,
                        r.field_angle_deg, r.orientation, r.shape) for r in _find(find_edges, half, min_edge / 2.0)]

        def measurer(c):
            return lambda box: measure_sfr_bayer(mosaic, meta.cfa, channel=c, box=box, method=method, **boot)
    else:
        idx = {"R": 0, "G": 1, "B": 2, "L": "luminance"}
        rois = _find(lambda a, **k: find_edges(a, encoding=encoding, **k), img, min_edge)

        def measurer(c):
            sel = idx[c] if colour else None
            return lambda box: measure_sfr(img, channel=sel, encoding=encoding, box=box, method=method, **boot)
    sensor = _sensor(w, h, pixel_um)
    if kind == "image" and img.dtype == np.uint8 and encoding == "linear":
        notes.append("8-bit image measured as linear codes; pass --encoding srgb if it is sRGB-encoded")
    first = measurer(chans[0])
    found, _ = _measure_rois(rois, first, progress)
    edges = [roi for roi, _ in found]
    if not edges:
        whole = _whole_frame_roi(first, w, h)
        if whole is None:
            raise IspError(f"{path}: no slanted edge found or measurable (neither a chart nor one edge filling "
                           "the frame)")
        edges = [whole]
        notes.append("no chart found: the whole image is one slanted edge")
    rows, cols = GRID
    regions = {(min(int(r.centre[1] / h * rows), rows - 1), min(int(r.centre[0] / w * cols), cols - 1))
               for r in edges}
    if len(regions) < MIN_REGIONS:
        split = []
        for roi in edges:
            length = roi.h if roi.direction == "vertical" else roi.w
            n = int(min(MAX_SEGMENTS, max(1, length // MIN_SEGMENT)))
            split += [_placed(s, w, h) for s in _segments(roi, n)]
        if len(split) > len(edges):
            notes.append(f"{len(edges)} edge(s) in {len(regions)} field region(s): split along the edge into "
                         f"{len(split)} segments of ≥ {MIN_SEGMENT} lines, measured one by one "
                         "(cross-validation over independent segments)")
        else:
            notes.append(f"{len(edges)} edge(s) in {len(regions)} field region(s), too short to split into "
                         f"segments of ≥ {MIN_SEGMENT} lines")
        edges = split
    parts = []
    for c in chans:
        ok, skipped = _measure_rois(edges, measurer(c), progress)
        if skipped:
            notes.append(f"{c}: {len(skipped)} ROI(s) skipped (e.g. {skipped[0][1]})")
        if not ok:
            continue
        o = Observations.from_sfr_results([_edge_item(roi, r, w, h) for roi, r in ok], sensor, channel=c,
                                          source=str(path))
        parts.append(_with_rois(o, [(roi.x, roi.y, roi.w, roi.h) for roi, _ in ok]))
    if not parts:
        raise IspError(f"{path}: no edge could be measured")
    meta_out = {"measure": kind, "encoding": encoding, "channels": chans}
    if kind == "raw":
        meta_out["cfa"] = meta.cfa.value if hasattr(meta.cfa, "value") else str(meta.cfa)
        if getattr(meta, "pixel_pitch_um", None):
            meta_out["pixel_pitch_um"] = float(meta.pixel_pitch_um)
    obs = _concat(parts, str(path), meta_out)
    return obs, notes


def _with_rois(obs, rois):
    return obs.with_fields(roi=np.array(rois, int))


def _find(finder, img, min_length):
    from calibration.sfr.esfr import SfrError

    try:
        return finder(img, min_length=min_length)
    except SfrError:
        return []


def observations_from_sfr_json(doc: dict, path: str, pixel_um: float | None = None):
    """Observations from the JSON of ``isp calib sfr`` (one ROI or
    ``--chart``), and notes."""
    from calibration.fit.observations import FREQ, Observations

    notes = []
    try:
        w, h = (int(v) for v in doc["size"])
        edges = doc["edges"]
        if not isinstance(edges, list) or not edges:
            raise IspError(f"{path}: no edges in this SFR JSON")
        cols = {k: [] for k in ("x", "y", "n", "ch", "o", "a", "sd", "noise", "step", "sfr")}
        no_step = 0
        for e in edges:
            x, y, rw, rh = (float(v) for v in e["roi"])
            direction = e.get("direction") or ("vertical" if rh >= rw else "horizontal")
            ang = float(e["angle_deg"])
            fit = e.get("edge_fit_linear")
            if fit is None:     # an older `isp calib sfr` JSON: the ROI centre, the unsigned angle
                c1 = math.tan(math.radians(ang))
                fit = ((x + rw / 2.0 - 0.5) - c1 * (y + rh / 2.0 - 0.5), c1) if direction == "vertical" else \
                      ((y + rh / 2.0 - 0.5) - c1 * (x + rw / 2.0 - 0.5), c1)
            cx, cy, normal, orient = _edge_place(direction, fit, (x, y, rw, rh), w, h)
            f = np.array(e["freq"], float)
            s = np.array([np.nan if v is None else v for v in e["sfr"]], float)
            step = e.get("step")
            if step is None:
                no_step += 1
                step = float("nan")
            cols["x"].append(cx)
            cols["y"].append(cy)
            cols["n"].append(normal)
            cols["ch"].append(str(e.get("channel") or ("G" if doc.get("kind") == "raw" else "L")))
            cols["o"].append(orient)
            if e.get("sfra") is None:
                raise IspError(f"{path}: edge at ROI {e['roi']} has no SFRA (null)")
            cols["a"].append(float(e["sfra"]))
            cols["sd"].append(float(e.get("sfra_std") or 2e-3))
            cols["noise"].append(float(e.get("noise") or 0.0))
            cols["step"].append(float(step))
            cols["sfr"].append(np.interp(FREQ, f, s, right=np.nan))
    except IspError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise IspError(f"{path}: not an `isp calib sfr` JSON or sfr-observations/v1 document "
                       f"({type(e).__name__}: {e})") from None
    if no_step:
        notes.append(f"{no_step} edge(s) without 'step' (an SFR JSON from an older `isp calib sfr`): their "
                     "noise cannot be scaled to the edge, so the noise floor is underestimated; re-measure")
    step = np.array(cols["step"])
    noise = np.where(np.isfinite(step), np.array(cols["noise"]), 0.0)
    obs = Observations(np.array(cols["x"]), np.array(cols["y"]), np.array(cols["n"]), np.array(cols["ch"]),
                       np.array(cols["o"]), np.array(cols["a"]), np.array(cols["sd"]), noise,
                       np.where(np.isfinite(step), step, 1.0), FREQ.copy(), np.array(cols["sfr"]),
                       _sensor(w, h, pixel_um), source=str(path), meta={"measure": "sfr-json"})
    return obs, notes


def load_measured(path: str, *, channel=None, encoding="linear", pixel_um=None, method="iso", min_edge=40.0,
                  progress=False, bootstrap: int = 0):
    """(Observations, notes) from a capture, an SFR JSON or an observations
    JSON (module docstring); bad input raises :class:`IspError` naming
    ``path``."""
    from calibration.fit.observations import Observations

    p = Path(path)
    if not p.exists():
        raise IspError(f"{path}: no such file")
    if p.is_dir():
        raise IspError(f"{path}: a folder, not a measurement file")
    if p.suffix.lower() == ".json":
        try:
            doc = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise IspError(f"{path}: not readable JSON ({e})") from None
        if not isinstance(doc, dict):
            raise IspError(f"{path}: not an `isp calib sfr` JSON or sfr-observations/v1 document")
        if doc.get("schema") == "sfr-observations/v1":
            try:
                return Observations.from_dict(doc, source=str(path)), []
            except (KeyError, TypeError, ValueError) as e:
                msg = str(e)
                raise IspError(msg if str(path) in msg else f"{path}: bad sfr-observations/v1 ({msg})") from None
        if "edges" in doc and "size" in doc:
            return observations_from_sfr_json(doc, str(path), pixel_um)
        schema = doc.get("schema")
        raise IspError(f"{path}: not an `isp calib sfr` JSON or sfr-observations/v1 document"
                       + (f" (schema {schema!r})" if schema else ""))
    from calibration.cli.main import load_image
    from calibration.sfr.esfr import SfrError

    try:
        img, kind, meta = load_image(path)
    except IspError as e:
        msg = str(e)
        raise IspError(msg if str(path) in msg else f"{path}: {msg}") from None
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    try:
        return observations_from_capture(img, kind, meta, path=str(path), channel=channel, encoding=encoding,
                                         pixel_um=pixel_um, method=method, min_edge=min_edge,
                                         progress=progress, bootstrap=bootstrap)
    except SfrError as e:
        raise IspError(f"{path}: {e}") from None


# -- base model ------------------------------------------------------------------------------

def match_sensor(nominal, obs, *, pixel_um: float | None = None):
    """The lens with the measurement's sensor, and the observations with
    the lens's pixel pitch.

    A capture's size wins (it is what was measured); its pitch comes from
    ``pixel_um``, else from the capture (raw metadata), else the lens
    file's sensor width in mm spread over the capture's width (as
    ``isp calib simulate --size`` does)."""
    from calibration.optics.lens import Sensor
    from calibration.fit.observations import Observations

    s, m = nominal.sensor, obs.sensor
    known = pixel_um or (obs.meta or {}).get("pixel_pitch_um")
    pitch = float(known or s.pixel_pitch_um * s.width_px / m.width_px)
    if (s.width_px, s.height_px, s.pixel_pitch_um) != (m.width_px, m.height_px, pitch):
        nominal = nominal.replace(sensor=Sensor(pixel_pitch_um=pitch, width_px=m.width_px, height_px=m.height_px))
    if abs(m.pixel_pitch_um - pitch) > 1e-12:
        d = obs.to_dict()
        d["sensor"]["pixel_pitch_um"] = pitch
        obs = Observations.from_dict(d, source=obs.source)
    return nominal, obs


def make_base(lens: str, obs, *, f_number="fit", n_params: int = 12, pixel_um: float | None = None,
              progress: bool = False):
    """The base model: ``"parametric"`` → :class:`ParametricBase` (F-number
    fitted from 2.0, or held at ``f_number``), else a lens file →
    :class:`LensBase`."""
    from calibration.loop.base import LensBase, ParametricBase

    if lens == "parametric":
        if f_number in (None, "fit"):
            return ParametricBase(obs, f_number=2.0, fit_f_number=True)
        return ParametricBase(obs, f_number=float(f_number))
    from calibration.cli.main import _load

    nominal = _load(lens)
    nominal, obs = match_sensor(nominal, obs, pixel_um=pixel_um)
    return LensBase(nominal, obs, n_params=n_params, progress=progress)


# -- figure --------------------------------------------------------------------------------

def model_sfr(base, xb, effects: dict) -> np.ndarray:
    """(N, F) noise-free SFR of ``base`` at ``xb`` with ``effects``
    ({name: {parameter: value}}), as the loop combines them."""
    from calibration.loop.effects import create_effect
    from calibration.loop.closure import predict_with_effects

    pairs = []
    for name, vals in effects.items():
        e = create_effect(name)
        pairs.append((e, np.array([vals[n] for n in e.names], float)))
    return predict_with_effects(base, xb, pairs).sfr


def plot_sfr_curves(obs, sfr_before, sfr_after, path, title: str = "") -> Path:
    """Measured SFR (mean over observations per channel, with its spread)
    against the model before and after the loop."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.cli.main import save_figure

    f = np.asarray(obs.freq)
    m = f <= 0.75
    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "L": "black"}
    ch = np.asarray(obs.channel)
    for c in sorted(set(ch.tolist())):
        sel = ch == c
        meas = np.asarray(obs.sfr)[sel][:, m]
        mu = np.nanmean(meas, axis=0)
        col = colours.get(c, "black")
        ax.fill_between(f[m], np.nanmin(meas, axis=0), np.nanmax(meas, axis=0), color=col, alpha=0.15, lw=0)
        ax.plot(f[m], mu, color=col, lw=1.6, label=f"measured {c}" + (f" ({sel.sum()})" if sel.sum() > 1 else ""))
        if sfr_before is not None:
            ax.plot(f[m], np.mean(sfr_before[sel][:, m], axis=0), color=col, lw=1.0, ls=":")
        ax.plot(f[m], np.mean(sfr_after[sel][:, m], axis=0), color=col, lw=1.0, ls="--")
    ax.plot([], [], color="gray", ls=":", label="base model (before)")
    ax.plot([], [], color="gray", ls="--", label="with effects (after)")
    ax.axvline(0.5, color="gray", lw=0.5)
    ax.set(xlabel="cycles / pixel", ylabel="SFR", xlim=(0, f[m][-1]), title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    save_figure(fig, path)
    return Path(path)


# -- the command ---------------------------------------------------------------------------

def _effect_names(text: str | None) -> list[str] | None:
    from calibration.loop.effects import list_effects

    if not text:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    known = list_effects()
    bad = [n for n in names if n not in known]
    if bad:
        raise IspError(f"--effects: unknown effect {bad[0]!r}; registered: {', '.join(known)}")
    return names


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise IspError(f"{out}: exists and is not a folder")


def _publish(tmp: Path, out: Path) -> None:
    """Move the finished report from ``tmp`` to ``out`` (a rename when
    ``out`` does not exist; file by file, each atomic, when it does)."""
    if not out.exists():
        os.replace(tmp, out)
        return
    for f in tmp.iterdir():
        os.replace(f, out / f.name)
    tmp.rmdir()


def _check_args(args) -> None:
    if args.f_number not in (None, "fit"):
        try:
            n = float(args.f_number)
        except ValueError:
            raise IspError(f"--f-number {args.f_number!r}: a number (e.g. 2.8) or `fit`") from None
        if not 0.5 <= n <= 64:
            raise IspError(f"--f-number {n:g}: outside 0.5–64")
    if args.folds < 2:
        raise IspError(f"--folds {args.folds}: at least 2")
    if args.max_effects < 0:
        raise IspError(f"--max-effects {args.max_effects}: 0 or more")
    if not 8 <= args.min_edge <= 10000:
        raise IspError(f"--min-edge {args.min_edge:g}: outside 8–10000 px")
    if args.pixel_um is not None and not 0.1 <= args.pixel_um <= 100:
        raise IspError(f"--pixel-um {args.pixel_um:g}: outside 0.1–100 µm")


def cmd_loop(args) -> int:
    import time

    from calibration.loop.closure import close_loop, write_report

    t0 = time.perf_counter()
    _check_args(args)
    out = Path(args.output)
    _check_out(out)
    effects = _effect_names(args.effects)
    if args.lens != "parametric":
        from calibration.cli.main import _load

        _load(args.lens)                        # a bad lens file fails before any measurement
    obs, notes = load_measured(args.measured, channel=args.channel, encoding=args.encoding,
                               pixel_um=args.pixel_um, method=args.method, min_edge=args.min_edge, progress=True)
    regions = len({tuple(r) for r in obs.region})
    if args.lens == "parametric" and not (args.pixel_um or (obs.meta or {}).get("pixel_pitch_um")):
        notes.append(f"pixel pitch unknown: {obs.sensor.pixel_pitch_um:g} µm assumed (--pixel-um); only "
                     "λN/pitch is identified")
    if regions < 2:
        hint = ("pass the capture itself, whose edges are then split into segments"
                if Path(args.measured).suffix.lower() == ".json" else "a longer edge or a chart is needed")
        notes.append("one field region: effects cannot be cross-validated (none will be added) and the noise "
                     f"floor cannot be fitted from the data; {hint}")
    for n in notes:
        print(f"note: {n}")
    print(f"{args.measured}: {len(obs)} observations in {regions} field region(s)")
    if args.lens != "parametric":
        print("loop: tracing the lens and screening its perturbations (a few minutes on 2 cores)", flush=True)
    base = make_base(args.lens, obs, f_number=args.f_number, n_params=args.n_params, pixel_um=args.pixel_um,
                     progress=True)
    obs = base.obs
    folds = max(2, min(args.folds, regions))
    if folds != args.folds:
        print(f"note: {folds} folds (the observations cover {regions} field region(s))")
    rep = close_loop(base, obs, effects=effects, folds=folds, max_effects=args.max_effects, progress=True,
                     seed=args.seed)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        write_report(rep, obs, tmp)
        _curves(base, rep, obs, tmp / "sfr_curves.png", args)
        _publish(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    print(summary(rep))
    print(f"wrote {out}/report.json, report.md, residual_maps.png, sfr_curves.png "
          f"({time.perf_counter() - t0:.0f} s)")
    return 0


def _curves(base, rep, obs, path, args) -> None:
    """The SFR figure: measured, base model before, model after."""
    try:
        before = model_sfr(base, rep.base_x_before, {})
        after = model_sfr(base, rep.base_x, rep.effect_values)
        plot_sfr_curves(obs, before, after, path, title=Path(args.measured).name)
    except Exception as e:                     # a figure must not lose the report
        print(f"loop: SFR curve plot skipped ({e})")


def summary(rep) -> str:
    """A few lines: effects added with values, error before/after, noise
    floor, what is left."""
    lines = []
    if rep.effects_added:
        for n in rep.effects_added:
            v = ", ".join(f"{k} = {x:.4g}" for k, x in rep.effect_values[n].items())
            lines.append(f"added {n}: {v}")
    else:
        lines.append("no effect added")
    b, a = rep.error_before, rep.error_after
    lines.append(f"SFRA RMS error {b['sfra_rms']:.4f} -> {a['sfra_rms']:.4f} cy/px "
                 f"(noise floor {rep.noise_floor:.4f}); SFR MSE {b['sfr_mse']:.3g} -> {a['sfr_mse']:.3g}; "
                 f"chi2/term {b['chi2_per_obs']:.2f} -> {a['chi2_per_obs']:.2f}")
    base = ", ".join(f"{k} = {float(v):.4g}" for k, v in zip(rep.base_names, rep.base_x))
    lines.append(f"base: {base}")
    lines += [f"left: {u}" for u in rep.unexplained[:1]]
    d = rep.decomposition_after.get("direction", {})   # measured − final model, by edge direction
    if len(d) == 2 and abs(d["vertical"] - d["horizontal"]) > 2 * rep.noise_floor:
        lines.append(f"left: vertical and horizontal edges differ: mean SFRA residual {d['vertical']:+.4f} "
                     f"(vertical) vs {d['horizontal']:+.4f} (horizontal) cy/px — an anisotropy no "
                     "effect tried models")
    return "\n".join(lines)


def add_parser(sub) -> None:
    """Register ``loop`` on the ``isp calib`` sub-parsers."""
    import argparse

    import textwrap

    from calibration.loop.effects import list_effects

    description = textwrap.fill(
        "Close the loop on a measurement: fit a base model (a lens file and its perturbations, or `parametric`: "
        "diffraction at F/N x aberration blur x pixel aperture) to the slanted-edge SFRs of a capture, estimate "
        "the noise floor from the data, decompose the residual (field position, orientation, channel, "
        "frequency), add the registry effect that best explains held-out data, refit, and repeat until the "
        "residual is at the noise floor or nothing helps.", 79)
    sp = sub.add_parser("loop", help="fit, find the effects the model lacks, refit; report before/after",
                        description=description, epilog=EPILOG,
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("--lens", required=True, metavar="LENS",
                    help="lens file (lens/v1 .json, Zemax .zmx, ...) or `parametric` for an unknown lens")
    sp.add_argument("--measured", required=True, metavar="MEAS",
                    help="chart capture (DNG/raw, PNG/TIFF/JPEG/BMP), SFR JSON of `isp calib sfr`, or "
                         "sfr-observations/v1 JSON")
    sp.add_argument("-o", "--output", default="loop_report", metavar="REPORT_DIR",
                    help="report folder (default loop_report/)")
    sp.add_argument("--effects", metavar="A,B,...",
                    help=f"registry effects to try (default all: {', '.join(list_effects())})")
    sp.add_argument("--max-effects", type=int, default=3, help="most effects to add (default 3)")
    sp.add_argument("--folds", type=int, default=3, help="cross-validation folds over field regions (default 3)")
    sp.add_argument("--channel", help="R, G, B, L (luminance of an RGB image) or all (default G; grey images: L)")
    sp.add_argument("--encoding", choices=("linear", "srgb"), default="linear",
                    help="how an image's codes relate to light (default linear; JPEGs are usually srgb)")
    sp.add_argument("--method", choices=("iso", "accurate"), default="iso", help="SFR method (isp calib sfr)")
    sp.add_argument("--min-edge", type=float, default=40.0, metavar="PX",
                    help="shortest chart edge used, pixels (default 40; shorter edges are noisier)")
    sp.add_argument("--f-number", default="fit", metavar="N|fit",
                    help="parametric base: F-number held at N, or fitted from 2.0 (default fit)")
    sp.add_argument("--pixel-um", type=float, metavar="UM",
                    help=f"pixel pitch, µm (default: the raw file's, else {DEFAULT_PIXEL_UM:g})")
    sp.add_argument("--n-params", type=int, default=12,
                    help="lens base: perturbations screened (default 12; on a simulated device perturbed in all "
                         "48, 24 left χ² 4.3 per term in 389 s against 12.6 in 279 s, README)")
    sp.add_argument("--seed", type=int, default=0, help="seed of the fold split and noise renders")
    sp.set_defaults(func=cmd_loop)
