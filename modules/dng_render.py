"""Adobe's rendering of a raw image: camera RGB to display sRGB as the DNG
SDK's ``dng_render`` does it.

The DNG specification leaves rendering to the reader; its reference
implementation, the Adobe DNG SDK, renders a fixed way, and that render is
what users compare a raw converter against (``dng_validate``, Adobe's
converters' defaults). This stage reproduces it from white-balanced,
demosaiced camera RGB:

===  ======================================================================
#    step (``dng_render_task::ProcessArea``)
===  ======================================================================
1    each camera channel clipped at the camera white (the white's camera
     neutral, largest entry 1) and at 0: a raw channel at or above its white
     level cannot tint the result; a pixel clipped in every channel is white
2    camera → linear ProPhoto RGB (the white-balance + camera matrix of
     DNG chapter 6, ForwardMatrix or inverse ColorMatrix interpolated by
     the white's temperature), clipped to [0, 1]
3    ProfileHueSatMap (interpolated by temperature), if the profile has one
4    exposure ramp per channel: black (the "shadows" default 5 × 0.001 ×
     ShadowScale, 0 with DefaultBlackRender = None) to 0, white
     ``2^−(BaselineExposure + BaselineExposureOffset + exposure)`` to 1,
     clipped
5    ProfileLookTable, if the profile has one
6    tone curve, hue-preserving (``RefBaselineRGBTone``): ProfileToneCurve,
     else Adobe's default ACR3 curve; a negative total exposure darkens the
     curve (exposure tone)
7    ProPhoto → linear sRGB, clipped to [0, 1], then the sRGB encoding
===  ======================================================================

DefaultCrop is applied by the reader; Orientation by the encoding stage.
The maths lives in :mod:`modules.common.dng_tone` (ramp, curves, RGB tone),
:mod:`modules.common.dng_profile` (HueSatMap, LookTable) and
:mod:`modules.common.dng_colour` (matrices). Step 1 is done on the balanced
data the pipeline carries: a balanced channel ``x_c = raw_c / n_c`` is
clipped at ``w_c / n_c``, ``w`` the camera white, ``n`` the applied neutral.

The frame is processed in strips of rows on OpenCV's thread count, so the
working memory beyond input and output is a few strips. One-dimensional
functions run as 65,536-entry tables indexed by the 16-bit-rounded input
(:func:`~modules.common.dng_tone.apply_lut16`); where the SDK itself uses a
4096-interval table (tone curve, output encoding), the 65,536 entries are
sampled from that table, so the SDK's interpolation is reproduced.

Not implemented (the SDK's less common paths): over-range (HDR) profiles
(``ProfileDynamicRange``), ProfileGainTableMap, RGBTables, monochrome and
four-colour negatives, Stage3BlackLevel.

References
----------
* Adobe Inc. *Digital Negative (DNG) Specification* 1.7.1.0 (2023), chapters
  4 and 6.
* Adobe DNG SDK 1.7.1 ``dng_render.cpp`` (dng_render, dng_render_task),
  ``dng_reference.cpp`` (RefBaselineABCtoRGB, RefBaselineHueSatMap,
  RefBaselineRGBTone, RefBaselineRGBtoRGB, RefBaseline1DTable).
* IEC 61966-2-1:1999 (sRGB), ISO 22028-2:2013 (ROMM RGB / ProPhoto).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.meta import CameraMeta
from isp.stage import StageBase

from modules.common.dng_colour import (SourceName, camera_to_prophoto, check_source,
                                       matrix_prophoto_to_srgb)
from modules.common.dng_profile import HueSatMap, apply_hue_sat_map, hue_sat_map_for_white, look_table
from modules.common.dng_tone import (acr3_default_tone_curve, apply_lut16, exposure_ramp,
                                     exposure_ramp_levels, exposure_tone, lut16, natural_spline,
                                     rgb_tone_planes, table_lookup, tabulate)

__all__ = ["DngRender", "RenderPlan", "TONE_CURVES", "render", "render_plan", "render_prophoto"]

#: Rows per strip: small enough for the temporaries of a 12 MP row band to
#: stay in the cache hierarchy, large enough to amortise the per-call cost.
STRIP_ROWS = 32

TONE_CURVES = {
    "auto": "the profile's ProfileToneCurve, else Adobe's default (ACR3)",
    "acr3": "Adobe Camera Raw 3's default curve, whatever the profile says",
    "linear": "no tone curve (the exposure ramp alone)",
}


@dataclass(frozen=True, eq=False)
class RenderPlan:
    """Everything the render needs, computed once per frame.

    Attributes
    ----------
    matrix : (3, 3) ndarray, float32
        Balanced camera RGB → linear ProPhoto RGB.
    limit : (3,) ndarray, float32
        Where each balanced channel clips (camera white / applied neutral);
        ``inf`` when the clip is off.
    hue_sat_map, look_table : HueSatMap or None
    hue_sat_encoding, look_encoding : int
        Value encodings of the tables (0 linear, 1 sRGB).
    ramp : (65536,) ndarray, float32
        The exposure ramp (:func:`~modules.common.dng_tone.lut16`).
    tone : (65536,) ndarray, float32
        Exposure tone followed by the tone curve, through the SDK's
        4096-interval table.
    to_srgb : (3, 3) ndarray, float32
        Linear ProPhoto → linear sRGB.
    encode : (65536,) ndarray, float32
        The sRGB encoding through the SDK's 4096-interval table.
    notes : tuple of str
    """

    matrix: np.ndarray
    limit: np.ndarray
    hue_sat_map: HueSatMap | None
    hue_sat_encoding: int
    look_table: HueSatMap | None
    look_encoding: int
    ramp: np.ndarray
    tone: np.ndarray
    to_srgb: np.ndarray
    encode: np.ndarray
    notes: tuple[str, ...]


def _srgb_encode(x):
    return np.where(x <= 0.0031308, 12.92 * x,
                    1.055 * np.power(np.maximum(x, 0.0031308), 1.0 / 2.4) - 0.055)


@lru_cache(maxsize=1)
def _encode_lut() -> np.ndarray:
    table = tabulate(_srgb_encode)
    return lut16(lambda x: table_lookup(table, x))


@lru_cache(maxsize=8)
def _ramp_lut(white: float, black: float) -> np.ndarray:
    return lut16(lambda x: exposure_ramp(x, white, black))


@lru_cache(maxsize=8)
def _tone_lut(exposure: float, curve: str, points: tuple | None) -> np.ndarray:
    if curve == "linear":
        base = None
    elif points is not None:
        base = natural_spline(np.asarray(points).reshape(-1, 2))
    else:
        base = acr3_default_tone_curve

    def total(x):
        y = exposure_tone(x, exposure)
        return y if base is None else base(y)

    table = tabulate(total)
    return lut16(lambda x: table_lookup(table, x))


def render_plan(meta: CameraMeta, neutral=None, *, exposure: float = 0.0, shadows: float = 5.0,
                tone_curve: str = "auto", hue_sat_map: bool = True, use_look_table: bool = True,
                clip_white: bool = True, source: SourceName = "auto") -> RenderPlan:
    """The matrices, tables and curves of Adobe's render for one capture.

    Parameters
    ----------
    meta : CameraMeta
    neutral : (3,) array_like, optional
        The neutral the data was balanced with (``Frame.neutral``); None
        for unbalanced camera RGB.
    exposure : float
        EV added to BaselineExposure + BaselineExposureOffset.
    shadows : float
        Adobe's shadows setting (5 by default; ignored, as 0, when the
        profile's DefaultBlackRender is 1).
    tone_curve : {"auto", "acr3", "linear"}
        See :data:`TONE_CURVES`.
    hue_sat_map, use_look_table : bool
        Apply the profile's tables when it has them.
    clip_white : bool
        Clip each camera channel at the camera white (step 1).
    source : str
        Camera matrices, as :data:`modules.common.dng_colour.SOURCES`.

    Returns
    -------
    RenderPlan

    Notes
    -----
    ``dng_render_task::Start``. Without a ColorMatrix the balanced camera
    RGB is taken as linear sRGB (white (1, 1, 1) at the clip), with a note.
    """
    if tone_curve not in TONE_CURVES:
        raise ValueError(f"unknown tone curve {tone_curve!r}; valid: {', '.join(TONE_CURVES)}")
    n = np.ones(3) if neutral is None else np.asarray(neutral, dtype=np.float64)
    notes = []
    if meta.color_matrix_1 is None and meta.color_matrix_2 is None:
        cam = np.linalg.inv(matrix_prophoto_to_srgb()) @ np.diag(1.0 / n)
        white = n / n.max()
        xy = None
        notes.append("no colour matrix: balanced camera RGB taken as linear sRGB")
    else:
        cam, white, xy, cnotes = camera_to_prophoto(meta, neutral=neutral, source=source)
        notes.append(cnotes[0])
    matrix = cam @ np.diag(n)
    limit = (white / n) if clip_white else np.full(3, np.inf)

    hsm, hsm_note = (hue_sat_map_for_white(meta, xy) if hue_sat_map and xy is not None
                     else (None, ""))
    if hsm_note:
        notes.append(hsm_note)
    lut = look_table(meta) if use_look_table else None
    if lut is not None:
        h, s, v = lut.divisions
        notes.append(f"LookTable {h}x{s}x{v}")

    total_ev = (meta.baseline_exposure or 0.0) + (meta.baseline_exposure_offset or 0.0) + exposure
    if not -32 <= total_ev <= 32:
        raise InputError(meta.path, f"exposure {total_ev:+.3g} EV is out of range")
    if meta.default_black_render == 1:
        shadows = 0.0
    white_level, black = exposure_ramp_levels(total_ev, shadows, meta.shadow_scale or 1.0)
    notes.append(f"exposure {total_ev:+.2f} EV: ramp white {white_level:.4g}, black {black:.4g}")
    points = None
    if tone_curve == "auto" and meta.profile_tone_curve is not None:
        points = tuple(np.asarray(meta.profile_tone_curve, dtype=np.float64).ravel().tolist())
        notes.append(f"ProfileToneCurve ({len(points) // 2} points)")
    else:
        notes.append({"auto": "ACR3 default tone curve", "acr3": "ACR3 default tone curve",
                      "linear": "no tone curve"}[tone_curve])
    return RenderPlan(
        matrix=matrix.astype(np.float32), limit=limit.astype(np.float32),
        hue_sat_map=hsm, hue_sat_encoding=meta.profile_hue_sat_map_encoding,
        look_table=lut, look_encoding=meta.profile_look_table_encoding,
        ramp=_ramp_lut(float(white_level), float(black)),
        tone=_tone_lut(float(total_ev), "linear" if tone_curve == "linear" else "curve", points),
        to_srgb=matrix_prophoto_to_srgb().astype(np.float32), encode=_encode_lut(),
        notes=tuple(notes))


def _prophoto_planes(rgb: np.ndarray, plan: RenderPlan) -> list[np.ndarray]:
    """Steps 1–6 as three contiguous planes."""
    import cv2

    x = cv2.min(rgb, tuple(float(v) for v in plan.limit) + (0.0,)) \
        if np.all(np.isfinite(plan.limit)) else rgb
    x = cv2.max(x, (0.0, 0.0, 0.0, 0.0))
    p = cv2.transform(x, plan.matrix)
    if plan.hue_sat_map is not None:
        np.clip(p, 0.0, 1.0, out=p)
        p = apply_hue_sat_map(p, plan.hue_sat_map, plan.hue_sat_encoding)
    p = apply_lut16(p, plan.ramp, out=p)  # the table's ends clip to [0, 1]
    if plan.look_table is not None:
        p = apply_hue_sat_map(p, plan.look_table, plan.look_encoding)
    r, g, b = cv2.split(p)
    return list(rgb_tone_planes(r, g, b, plan.tone))


def render_prophoto(rgb: np.ndarray, plan: RenderPlan) -> np.ndarray:
    """Steps 1–6 on an array: balanced camera RGB → tone-mapped linear
    ProPhoto RGB in [0, 1].

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32
        Balanced camera RGB, white level 1.
    plan : RenderPlan

    Returns
    -------
    (H, W, 3) ndarray, float32
    """
    import cv2

    return cv2.merge(_prophoto_planes(np.ascontiguousarray(rgb, dtype=np.float32), plan))


def _render_strip(src: np.ndarray, dst: np.ndarray, plan: RenderPlan) -> None:
    import cv2

    s = cv2.transform(render_prophoto(src, plan), plan.to_srgb)
    apply_lut16(s, plan.encode, out=dst)


def render(rgb: np.ndarray, plan: RenderPlan, threads: int | None = None,
           out: np.ndarray | None = None) -> np.ndarray:
    """Steps 1–7: balanced camera RGB → display sRGB in [0, 1].

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32
    plan : RenderPlan
    threads : int, optional
        Strips processed at once; default OpenCV's thread count.
    out : (H, W, 3) ndarray, float32, optional
        Where to write; may be ``rgb`` itself (each strip is read whole
        before it is written), which saves a frame of memory when the
        caller no longer needs the input.

    Returns
    -------
    (H, W, 3) ndarray, float32, sRGB-encoded, in [0, 1].
    """
    import cv2

    rgb = np.asarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected (H, W, 3) camera RGB, got shape {rgb.shape}")
    if out is None:
        out = np.empty(rgb.shape, np.float32)
    elif out.shape != rgb.shape or out.dtype != np.float32:
        raise ValueError(f"out must be float32 of shape {rgb.shape}, got {out.dtype} {out.shape}")
    h = rgb.shape[0]
    starts = range(0, h, STRIP_ROWS)
    n = max(1, threads if threads is not None else cv2.getNumThreads())
    if n == 1 or h <= STRIP_ROWS:
        for y in starts:
            _render_strip(rgb[y:y + STRIP_ROWS], out[y:y + STRIP_ROWS], plan)
        return out
    # numpy and OpenCV release the GIL inside each call; the strips share nothing
    with ThreadPoolExecutor(n, thread_name_prefix="dng-render") as pool:
        for f in [pool.submit(_render_strip, rgb[y:y + STRIP_ROWS], out[y:y + STRIP_ROWS], plan)
                  for y in starts]:
            f.result()
    return out


@dataclass(frozen=True)
class DngRender(StageBase):
    """Render camera RGB as Adobe's DNG SDK does: camera profile, exposure
    ramp, tone curve, sRGB (see the module docstring for the steps).

    Parameters
    ----------
    exposure : float
        EV added to BaselineExposure + BaselineExposureOffset (Adobe's
        exposure setting), within ±16.
    shadows : float
        Adobe's shadows setting: the black point in thousandths of white
        (5 by default); ignored when the profile's DefaultBlackRender is 1.
    tone_curve : {"auto", "acr3", "linear"}
        ``auto``: the profile's ProfileToneCurve, else the ACR3 default.
    hue_sat_map, look_table : bool
        Apply the profile's ProfileHueSatMap / ProfileLookTable when present.
    clip_white : bool
        Clip each camera channel at the camera white before the matrix, as
        Adobe does: clipped highlights render neutral. Off, values above it
        pass to the matrix (and are clipped after it).
    source : str
        Camera matrices: ``auto`` (ForwardMatrix when present),
        ``color_matrix``, ``forward_matrix``, ``color_matrix_1``,
        ``color_matrix_2``.
    """

    name = "dng_render"
    consumes = (Domain.CAMERA_RGB,)
    produces = Domain.DISPLAY_RGB

    exposure: float = 0.0
    shadows: float = 5.0
    tone_curve: Literal["auto", "acr3", "linear"] = "auto"
    hue_sat_map: bool = True
    look_table: bool = True
    clip_white: bool = True
    source: SourceName = "auto"

    def __post_init__(self):
        if not (math.isfinite(self.exposure) and -16 <= self.exposure <= 16):
            raise ValueError(f"exposure must be within ±16 EV, got {self.exposure}")
        if not (math.isfinite(self.shadows) and 0 <= self.shadows <= 100):
            raise ValueError(f"shadows must be in [0, 100], got {self.shadows}")
        if self.tone_curve not in TONE_CURVES:
            raise ValueError(f"unknown tone curve {self.tone_curve!r}; valid: {', '.join(TONE_CURVES)}")
        check_source(self.source)

    def plan(self, frame: Frame) -> RenderPlan:
        """The :class:`RenderPlan` for ``frame``."""
        return render_plan(frame.meta, frame.neutral, exposure=self.exposure, shadows=self.shadows,
                           tone_curve=self.tone_curve, hue_sat_map=self.hue_sat_map,
                           use_look_table=self.look_table, clip_white=self.clip_white,
                           source=self.source)

    def process(self, frame: Frame) -> Frame:
        plan = self.plan(frame)
        out = render(frame.data, plan)
        return frame.evolve(out, domain=Domain.DISPLAY_RGB, stage=self.name,
                            note="; ".join(plan.notes))
