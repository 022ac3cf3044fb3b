"""Camera-profile tables: ProfileHueSatMap and ProfileLookTable.

A DNG camera profile may carry two kinds of hue/saturation/value tables that
Adobe's renderer applies in its working space (linear ProPhoto RGB):

* **HueSatMap** (ProfileHueSatMapData1/2/3), applied right after the camera
  matrix, before exposure; with two tables they are interpolated by the
  scene white's colour temperature, as the matrices are;
* **LookTable** (ProfileLookTableData), applied after the exposure ramp,
  before the tone curve.

Each entry of a table holds a hue shift (degrees), a saturation scale and a
value scale at one node of a grid over hue (cyclic), saturation and value.
A pixel is converted to HSV, the three modifiers are interpolated from the
grid (bilinearly over hue and saturation for a 2.5-D table with one value
division, trilinearly otherwise), applied, and the pixel converted back.

==========================  ==================================================
step                        as the DNG SDK does it (``RefBaselineHueSatMap``)
==========================  ==================================================
RGB → HSV                   ``v = max``, ``s = (max − min)/max``, hue in
                            [0, 6) from the largest channel
                            (``DNG_RGBtoHSV``); grey has h = s = 0
grid position               ``h · H/6`` (0 when ``H < 2``), ``s · (S − 1)``,
                            ``v_enc · (V − 1)``; the lower index is capped so
                            that the upper one exists, and hue wraps from the
                            last division to the first
value encoding              for a 3-D table with encoding 1 (sRGB), the value
                            axis is sRGB-encoded (4096-interval tables of the
                            sRGB curve and its inverse)
modification                ``h += shift · 6/360``; ``s = min(s · scale, 1)``;
                            ``v_enc = clip(v_enc · scale, 0, 1)``, decoded
                            through the inverse table whenever the encoding
                            is sRGB (for a 2.5-D table too, where the value
                            was not encoded: the SDK's behaviour, kept)
HSV → RGB                   the standard sextant formula (``DNG_HSVtoRGB``)
==========================  ==================================================

Storage (``dng_camera_profile::ReadHueSatMap``): value outermost, then hue,
then saturation; a table may omit the zero-saturation column, which then
takes the first column's hue shift and saturation scale with value scale 1;
a stored zero-saturation entry always has its value scale forced to 1.

References
----------
* Adobe Inc. *Digital Negative (DNG) Specification* 1.7.1.0 (2023), chapter 4:
  ProfileHueSatMapDims, ProfileHueSatMapData1/2/3, ProfileHueSatMapEncoding,
  ProfileLookTableDims, ProfileLookTableData, ProfileLookTableEncoding;
  chapter 6 (interpolation by colour temperature).
* Adobe DNG SDK 1.7.1: ``dng_hue_sat_map.cpp`` (SetDelta, Interpolate),
  ``dng_camera_profile.cpp`` (ReadHueSatMap, HueSatMapForWhite_Dual,
  BuildHueSatMapEncodingTable), ``dng_reference.cpp``
  (RefBaselineHueSatMap), ``dng_utils.h`` (DNG_RGBtoHSV, DNG_HSVtoRGB).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from isp.meta import CameraMeta

from modules.common.dng_colour import illuminant_to_cct, interpolation_weight, xy_to_cct
from modules.common.dng_tone import table_lookup, tabulate

__all__ = [
    "ENCODINGS",
    "HueSatMap",
    "apply_hue_sat_map",
    "hsv_to_rgb",
    "hue_sat_map_for_white",
    "look_table",
    "rgb_to_hsv",
]

#: Value-axis encodings of ProfileHueSatMapEncoding / ProfileLookTableEncoding.
ENCODINGS = {0: "linear", 1: "sRGB"}


@dataclass(frozen=True, eq=False)
class HueSatMap:
    """A hue/saturation/value modification table.

    Parameters
    ----------
    deltas : (V, H, S, 3) ndarray, float32
        Per node: hue shift (degrees), saturation scale, value scale; V value
        divisions (1 for a 2.5-D table), H hue divisions (cyclic), S ≥ 2
        saturation divisions from s = 0 to 1.
    """

    deltas: np.ndarray

    def __post_init__(self):
        d = np.asarray(self.deltas, dtype=np.float32)
        if d.ndim != 4 or d.shape[-1] != 3 or d.shape[0] < 1 or d.shape[1] < 1 or d.shape[2] < 2:
            raise ValueError(f"a hue/sat map needs (vals >= 1, hues >= 1, sats >= 2, 3) deltas, "
                             f"got shape {d.shape}")
        if not np.all(np.isfinite(d)):
            raise ValueError("hue/sat map has non-finite entries")
        object.__setattr__(self, "deltas", d)

    @property
    def planes(self) -> np.ndarray:
        """(3, V·H·S) float32: hue shifts, saturation scales and value
        scales as contiguous rows, indexed ``(v·H + h)·S + s``."""
        cached = self.__dict__.get("_planes")
        if cached is None:
            cached = np.ascontiguousarray(self.deltas.reshape(-1, 3).T)
            object.__setattr__(self, "_planes", cached)
        return cached

    @property
    def divisions(self) -> tuple[int, int, int]:
        """(hues, sats, vals), the order of ProfileHueSatMapDims."""
        v, h, s, _ = self.deltas.shape
        return h, s, v

    @classmethod
    def from_tag(cls, dims, data) -> "HueSatMap":
        """The table of a ProfileHueSatMapData / ProfileLookTableData tag.

        Parameters
        ----------
        dims : (hues, sats, vals)
            From the matching ``*Dims`` tag (vals 0 means 1).
        data : array_like
            The tag's floats: ``hues·sats·vals·3``, or ``hues·(sats−1)·vals·3``
            without the zero-saturation column.

        Returns
        -------
        HueSatMap

        Examples
        --------
        >>> m = HueSatMap.from_tag((2, 2, 1), [10, 2, 3, 20, 4, 5])   # sat 0 omitted
        >>> m.deltas[0, :, 0].tolist()   # filled from sat 1, value scale 1
        [[10.0, 2.0, 1.0], [20.0, 4.0, 1.0]]
        """
        hues, sats, vals = (int(v) for v in dims)
        vals = max(vals, 1)
        a = np.asarray(data, dtype=np.float32).ravel()
        if a.size == hues * sats * vals * 3:
            d = a.reshape(vals, hues, sats, 3).copy()
        elif a.size == hues * (sats - 1) * vals * 3:
            d = np.empty((vals, hues, sats, 3), np.float32)
            d[:, :, 1:] = a.reshape(vals, hues, sats - 1, 3)
            d[:, :, 0] = d[:, :, 1]
        else:
            raise ValueError(f"{a.size} values do not fill a {hues}x{sats}x{vals} table of triplets")
        d[:, :, 0, 2] = 1.0  # the zero-saturation entry's value scale is 1 (SetDelta)
        return cls(d)

    @staticmethod
    def interpolate(map1: "HueSatMap", map2: "HueSatMap", weight1: float) -> "HueSatMap":
        """``w·map1 + (1 − w)·map2`` entry by entry (``dng_hue_sat_map::Interpolate``).

        Examples
        --------
        >>> a = HueSatMap(np.zeros((1, 1, 2, 3))); b = HueSatMap(np.ones((1, 1, 2, 3)))
        >>> HueSatMap.interpolate(a, b, 0.25).deltas[0, 0, 1].tolist()
        [0.75, 0.75, 0.75]
        """
        if weight1 >= 1.0:
            return map1
        if weight1 <= 0.0:
            return map2
        if map1.deltas.shape != map2.deltas.shape:
            raise ValueError(f"hue/sat maps of different sizes: {map1.divisions} and {map2.divisions}")
        w1 = np.float32(weight1)
        return HueSatMap(w1 * map1.deltas + (np.float32(1.0) - w1) * map2.deltas)


def _table(meta: CameraMeta, field: str) -> HueSatMap | None:
    data = getattr(meta, field)
    dims = meta.profile_look_table_dims if field == "profile_look_table_data" \
        else meta.profile_hue_sat_map_dims
    if data is None or dims is None:
        return None
    return HueSatMap.from_tag(dims, data)


def hue_sat_map_for_white(meta: CameraMeta, white_xy) -> tuple[HueSatMap | None, str]:
    """The HueSatMap for a scene white: table 1, or tables 1 and 2
    interpolated by colour temperature.

    Parameters
    ----------
    meta : CameraMeta
        ``profile_hue_sat_map_*`` and CalibrationIlluminant1/2.
    white_xy : (2,) array_like
        The scene white (from :func:`~modules.common.dng_colour.camera_to_prophoto`).

    Returns
    -------
    table : HueSatMap or None
        None when the profile has no ProfileHueSatMapData1.
    note : str
        What was used, for the stage's note.

    Notes
    -----
    ``dng_camera_profile::HueSatMapForWhite_Dual``: with both tables and
    two distinct calibration temperatures, weight ``g`` of table 1 linear in
    inverse CCT between them, clamped to [0, 1] (as the matrices,
    :func:`~modules.common.dng_colour.interpolation_weight`); otherwise
    table 1 alone. A profile with only table 2 has no HueSatMap in the SDK.
    Triple-illuminant profiles (table 3) are interpolated as dual ones.
    """
    m1 = _table(meta, "profile_hue_sat_map_data_1")
    if m1 is None:
        return None, ""
    m2 = _table(meta, "profile_hue_sat_map_data_2")
    h, s, v = m1.divisions
    size = f"{h}x{s}x{v}"
    if m2 is None:
        return m1, f"HueSatMap {size}"
    t1 = illuminant_to_cct(meta.calibration_illuminant_1)
    t2 = illuminant_to_cct(meta.calibration_illuminant_2)
    if not t1 or not t2 or t1 == t2:
        return m1, f"HueSatMap {size} (table 1: no temperatures to interpolate)"
    g = interpolation_weight(xy_to_cct(white_xy), t1, t2)
    return HueSatMap.interpolate(m1, m2, g), f"HueSatMap {size} (weight {g:.3f} on table 1)"


def look_table(meta: CameraMeta) -> HueSatMap | None:
    """The profile's LookTable, or None."""
    return _table(meta, "profile_look_table_data")


# --------------------------------------------------------------------------
# HSV as the SDK defines it (hue in [0, 6))

def rgb_to_hsv(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hue, saturation, value of RGB (``DNG_RGBtoHSV``).

    Parameters
    ----------
    rgb : (..., 3) ndarray, float32
        Non-negative values.

    Returns
    -------
    h, s, v : (...) ndarrays, float32
        Hue in [0, 6) (0 red, 2 green, 4 blue), saturation in [0, 1],
        value = max(R, G, B); grey has h = s = 0.

    Examples
    --------
    >>> [float(c) for c in rgb_to_hsv(np.array([0.5, 1.0, 0.0], np.float32))]
    [1.5, 1.0, 1.0]
    """
    rgb = np.asarray(rgb, dtype=np.float32)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    v = np.maximum(np.maximum(r, g), b)
    gap = v - np.minimum(np.minimum(r, g), b)
    pos = gap > 0
    safe = np.where(pos, gap, np.float32(1.0))
    h = np.where(r == v, (g - b) / safe,
                 np.where(g == v, 2.0 + (b - r) / safe, 4.0 + (r - g) / safe)).astype(np.float32)
    h = np.where(h < 0, h + np.float32(6.0), h)
    h = np.where(pos, h, np.float32(0.0))
    s = np.where(pos, gap / np.where(v > 0, v, np.float32(1.0)), np.float32(0.0)).astype(np.float32)
    return h, s, v


def hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """RGB of hue (any real, taken modulo 6), saturation and value
    (``DNG_HSVtoRGB``).

    Returns
    -------
    (..., 3) ndarray, float32

    Notes
    -----
    The sextant formula written without branches: channel ``n`` (5 for R,
    3 for G, 1 for B) is ``v − v·s·clip(min(k, 4 − k), 0, 1)`` with
    ``k = (n + h) mod 6``, equal to the SDK's ``p, q, t`` cases.

    Examples
    --------
    >>> hsv_to_rgb(np.float32(1.5), np.float32(1.0), np.float32(1.0)).tolist()
    [0.5, 1.0, 0.0]
    """
    h = np.asarray(h, dtype=np.float32)
    s = np.asarray(s, dtype=np.float32)
    v = np.asarray(v, dtype=np.float32)
    vs = v * s
    out = []
    for n in (5.0, 3.0, 1.0):
        k = np.mod(h + np.float32(n), np.float32(6.0))
        w = np.clip(np.minimum(k, np.float32(4.0) - k), np.float32(0.0), np.float32(1.0))
        out.append(v - w * vs)
    return np.stack(out, axis=-1)


@lru_cache(maxsize=1)
def _srgb_tables() -> tuple[np.ndarray, np.ndarray]:
    """4096-interval tables of the sRGB encoding and its inverse
    (``BuildHueSatMapEncodingTable``, ``dng_function_GammaEncode_sRGB``)."""
    def encode(x):
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308),
                                                                   1.0 / 2.4) - 0.055)

    def decode(y):
        return np.where(y <= 0.0031308 * 12.92, y / 12.92,
                        np.power((np.maximum(y, 0.0031308 * 12.92) + 0.055) / 1.055, 2.4))

    return tabulate(encode), tabulate(decode)


def apply_hue_sat_map(rgb: np.ndarray, table: HueSatMap, encoding: int = 0) -> np.ndarray:
    """Apply a HueSatMap or LookTable to linear RGB (``RefBaselineHueSatMap``).

    Parameters
    ----------
    rgb : (..., 3) ndarray, float32
        Linear ProPhoto RGB in [0, 1].
    table : HueSatMap
    encoding : {0, 1}
        The table's value encoding (0 linear, 1 sRGB; :data:`ENCODINGS`).

    Returns
    -------
    (..., 3) ndarray, float32

    Notes
    -----
    See the module table. For a 2.5-D table (one value division) the
    modifiers are bilinear in (hue, saturation); for a 3-D table trilinear
    in (hue, saturation, encoded value). Hue wraps: between the last hue
    division and the first the interpolation runs across 360°.

    Examples
    --------
    An identity table leaves colours as they are:

    >>> ident = HueSatMap(np.tile(np.array([0, 1, 1], np.float32), (1, 6, 3, 1)))
    >>> x = np.array([[0.2, 0.5, 0.1]], np.float32)
    >>> bool(np.allclose(apply_hue_sat_map(x, ident), x, atol=1e-6))
    True
    """
    if encoding not in ENCODINGS:
        raise ValueError(f"unknown value encoding {encoding!r}; valid: 0 (linear), 1 (sRGB)")
    rgb = np.asarray(rgb, dtype=np.float32)
    shape = rgb.shape
    h, s, v = rgb_to_hsv(rgb.reshape(-1, 3))
    hues, sats, vals = table.divisions
    planes = table.planes
    h_scale = np.float32(hues / 6.0) if hues >= 2 else np.float32(0.0)
    hs = h * h_scale
    h0 = hs.astype(np.int32)
    ss = s * np.float32(sats - 1)
    s0 = np.minimum(ss.astype(np.int32), sats - 2)
    wrap = h0 >= hues - 1
    h0[wrap] = hues - 1
    fh = hs - h0.astype(np.float32)
    fs = ss - s0.astype(np.float32)
    # flat index of the (h0, s0) node and the step to the next hue node
    # (back to hue 0 from the last division)
    base = (h0 * sats + s0).astype(np.intp)
    step_h = np.where(wrap, -(hues - 1) * sats, sats).astype(np.intp)
    tables = _srgb_tables() if encoding == 1 else None
    v_enc = v
    corners = [(base, (1 - fh) * (1 - fs)), (base + step_h, fh * (1 - fs)),
               (base + 1, (1 - fh) * fs), (base + step_h + 1, fh * fs)]
    if vals >= 2:
        if tables is not None:
            v_enc = table_lookup(tables[0], v)
        vsc = v_enc * np.float32(vals - 1)
        v0 = np.minimum(vsc.astype(np.int32), vals - 2)
        fv = vsc - v0.astype(np.float32)
        offset = v0.astype(np.intp) * (hues * sats)
        plane = hues * sats
        corners = [(i + offset, w * (1 - fv)) for i, w in corners] + \
                  [(i + offset + plane, w * fv) for i, w in corners]
    mod = []
    tmp = np.empty_like(h)
    for c in range(3):
        acc = np.zeros_like(h)
        for idx, w in corners:
            np.take(planes[c], idx, out=tmp)
            tmp *= w
            acc += tmp
        mod.append(acc)
    h = h + mod[0] * np.float32(6.0 / 360.0)
    s = np.minimum(s * mod[1], np.float32(1.0))
    v_enc = np.clip(v_enc * mod[2], 0.0, 1.0)
    v = table_lookup(tables[1], v_enc) if tables is not None else v_enc
    return hsv_to_rgb(h, s, v).reshape(shape)
