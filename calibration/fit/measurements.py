"""Measurements as :class:`~calibration.fit.observations.Observations`: a
chart capture, the JSON of ``isp calib sfr``, or an ``sfr-observations/v1``
file (:func:`load_measured`), and a lens matched to the measurement's
sensor (:func:`match_sensor`).

A measurement is one of

* a capture: a raw file (DNG, ...; edges found on the 2×2-block average and
  measured on the Bayer mosaic per colour) or an image (PNG/TIFF/JPEG/BMP,
  measured as linear codes unless ``encoding="srgb"``). A chart is searched
  for slanted edges (:mod:`calibration.sfr.chart`); an image where none is
  found is taken as one slanted edge filling the frame (the ISO 12233 ROI
  files); :func:`observations_from_capture`;
* the JSON of ``isp calib sfr`` (one ROI or ``--chart``;
  :func:`observations_from_sfr_json`);
* an ``sfr-observations/v1`` JSON
  (:meth:`~calibration.fit.observations.Observations.save`).

Sensor geometry: a raw file gives its own size and, where its metadata
holds it, the pixel pitch; an image of an unknown camera is taken as the
full field (optical centre at the image centre) at ``pixel_um``
(default :data:`DEFAULT_PIXEL_UM`). With a parametric base only λN/pitch is
identifiable, so the fitted F-number is at that assumed pitch.

Few edges. The loop ranks effects by K-fold cross-validation over *field
regions* and fits the noise law σ ∝ noise/step over the observations
(:mod:`calibration.loop.closure`), so it needs observations in at least
:data:`MIN_REGIONS` regions. A capture with fewer measurable edges (a
single-edge ROI file) has each edge split along its length into segments of
at least :data:`MIN_SEGMENT` lines (up to :data:`MAX_SEGMENTS` per edge),
each measured on its own. Why segments rather than cross-validating over
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

Imports :mod:`calibration.sfr`, :mod:`calibration.optics.lens`,
:mod:`calibration.fit.observations` and ``isp`` errors.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from calibration.sfr.esfr import DEFAULT_METHOD
from calibration.sfr.images import load_image
from isp.errors import ConfigError, InputError, IspError

__all__ = ["CHANNELS", "DEFAULT_PIXEL_UM", "MAX_SEGMENTS", "MIN_REGIONS", "MIN_SEGMENT", "load_measured",
           "match_sensor", "observations_from_capture", "observations_from_sfr_json"]


MIN_SEGMENT = 64
"""Lines along the edge per segment of a split edge (≥ 6 phase cycles at 5°)."""
MAX_SEGMENTS = 4
"""Segments an edge is split into at most."""
MIN_REGIONS = 3
"""Field regions below which a capture's edges are split into segments."""
DEFAULT_PIXEL_UM = 1.0
"""Pixel pitch (µm) of an image whose camera is unknown."""
CHANNELS = {"r": "R", "g": "G", "b": "B", "l": "L", "luminance": "L", "y": "L", "all": "all"}
"""Channel names accepted (any case) and the colour each measures."""


def _channels(channel: str | None, kind: str, colour: bool, path: str, notes: list) -> list[str]:
    """The colours to measure: R, G, B ("all": the three), L (luminance of
    an RGB image); a grey image has L only."""
    c = CHANNELS.get((channel or "G").strip().lower())
    if c is None:
        raise ConfigError(f"--channel {channel!r}: valid: R, G, B, L (luminance of an RGB image), all")
    if kind == "raw" and c == "L":
        raise InputError(path, "--channel L is for RGB images; a raw file has R, G, B (or all)")
    if kind != "raw" and not colour:
        if channel is not None and c != "L":
            notes.append(f"grey image: --channel {channel} ignored")
        return ["L"]
    return ["R", "G", "B"] if c == "all" else [c]


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


def _measure_rois(rois, measure, executor) -> tuple[list, list]:
    from isp.runtime.executor import create_executor

    from calibration.sfr.chart import measure_rois

    few = executor is None or len(rois) <= 8          # no bar for a handful of edges
    return measure_rois(rois, measure, executor=create_executor("serial") if few else executor)


def observations_from_capture(img, kind: str, meta=None, *, path: str = "", channel: str | None = None,
                              encoding: str = "linear", pixel_um: float | None = None, method: str = DEFAULT_METHOD,
                              min_edge: float = 40.0, bootstrap: int = 0, executor=None):
    """Observations measured on a capture, and notes on how.

    Parameters
    ----------
    img : (H, W) or (H, W, 3) ndarray
        An image (codes) or, with ``kind == "raw"``, a linear Bayer mosaic
        (black level removed), as :func:`calibration.sfr.images.load_image` returns.
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
    executor : isp.runtime.executor.Executor, optional
        Measures the edges ("serial" or "threads"; default "serial"); its
        progress bar counts them where there are more than 8.

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
    found, _ = _measure_rois(rois, first, executor)
    edges = [roi for roi, _ in found]
    if not edges:
        whole = _whole_frame_roi(first, w, h)
        if whole is None:
            raise InputError(path, "no slanted edge found or measurable (neither a chart nor one edge filling "
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
        ok, skipped = _measure_rois(edges, measurer(c), executor)
        if skipped:
            notes.append(f"{c}: {len(skipped)} ROI(s) skipped (e.g. {skipped[0][1]})")
        if not ok:
            continue
        o = Observations.from_sfr_results([_edge_item(roi, r, w, h) for roi, r in ok], sensor, channel=c,
                                          source=str(path))
        parts.append(_with_rois(o, [(roi.x, roi.y, roi.w, roi.h) for roi, _ in ok]))
    if not parts:
        raise InputError(path, "no edge could be measured")
    meta_out = {"measure": kind, "encoding": encoding, "channels": chans, "sfr_method": method}
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
            raise InputError(path, "no edges in this SFR JSON")
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
                raise InputError(path, f"edge at ROI {e['roi']} has no SFRA (null)")
            cols["a"].append(float(e["sfra"]))
            cols["sd"].append(float(e.get("sfra_std") or 2e-3))
            cols["noise"].append(float(e.get("noise") or 0.0))
            cols["step"].append(float(step))
            cols["sfr"].append(np.interp(FREQ, f, s, right=np.nan))
    except IspError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(path, f"not an `isp calib sfr` JSON or sfr-observations/v1 document "
                               f"({type(e).__name__}: {e})") from None
    if no_step:
        notes.append(f"{no_step} edge(s) without 'step' (an SFR JSON from an older `isp calib sfr`): their "
                     "noise cannot be scaled to the edge, so the noise floor is underestimated; re-measure")
    step = np.array(cols["step"])
    noise = np.where(np.isfinite(step), np.array(cols["noise"]), 0.0)
    obs = Observations(np.array(cols["x"]), np.array(cols["y"]), np.array(cols["n"]), np.array(cols["ch"]),
                       np.array(cols["o"]), np.array(cols["a"]), np.array(cols["sd"]), noise,
                       np.where(np.isfinite(step), step, 1.0), FREQ.copy(), np.array(cols["sfr"]),
                       _sensor(w, h, pixel_um), source=str(path), meta={"measure": "sfr-json", "sfr_method": str(doc.get("method", "iso"))})
    return obs, notes


def load_measured(path: str, *, channel=None, encoding="linear", pixel_um=None, method=DEFAULT_METHOD, min_edge=40.0,
                  bootstrap: int = 0, executor=None):
    """(Observations, notes) from a capture, an SFR JSON or an observations
    JSON (module docstring); bad input raises
    :class:`~isp.errors.InputError` naming ``path``. A capture's edges are
    measured on ``executor`` (:func:`observations_from_capture`)."""
    from calibration.fit.observations import Observations

    p = Path(path)
    if not p.exists():
        raise InputError(path, "no such file")
    if p.is_dir():
        raise InputError(path, "a folder, not a measurement file")
    if p.suffix.lower() == ".json":
        try:
            doc = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise InputError(path, f"not readable JSON ({e})") from None
        if not isinstance(doc, dict):
            raise InputError(path, "not an `isp calib sfr` JSON or sfr-observations/v1 document")
        if doc.get("schema") == "sfr-observations/v1":
            try:
                return Observations.from_dict(doc, source=str(path)), []
            except (KeyError, TypeError, ValueError) as e:
                msg = str(e)
                raise (InputError(None, msg) if str(path) in msg
                       else InputError(path, f"bad sfr-observations/v1 ({msg})")) from None
        if "edges" in doc and "size" in doc:
            return observations_from_sfr_json(doc, str(path), pixel_um)
        schema = doc.get("schema")
        raise InputError(path, "not an `isp calib sfr` JSON or sfr-observations/v1 document"
                         + (f" (schema {schema!r})" if schema else ""))
    from calibration.sfr.esfr import SfrError

    try:
        img, kind, meta = load_image(path)
    except IspError as e:
        msg = str(e)
        raise (InputError(None, msg) if str(path) in msg else InputError(path, msg)) from None
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    try:
        return observations_from_capture(img, kind, meta, path=str(path), channel=channel, encoding=encoding,
                                         pixel_um=pixel_um, method=method, min_edge=min_edge,
                                         bootstrap=bootstrap, executor=executor)
    except SfrError as e:
        raise InputError(path, str(e)) from None


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
