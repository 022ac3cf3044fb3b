"""DNG tags → :class:`~isp.meta.CameraMeta` fields, read with tifffile.

Reference: Adobe, *Digital Negative (DNG) Specification* 1.7.1.0 (2023),
chapter 4 (tags). Tag values arrive from tifffile as Python scalars, tuples
(rationals as flat ``(num, den, num, den, ...)``) or bytes.

Decisions the specification leaves to the reader, and what this module does:

* a rational with denominator 0 (``0/0`` BaselineExposure, seen in the wild)
  is *absent*, not NaN; the decision is noted;
* a ColorMatrix without its CalibrationIlluminant is kept, its illuminant
  left ``None``: with one matrix nothing is interpolated, so the illuminant
  does not matter; with two, the colour stage cannot interpolate and uses
  the first; both cases are noted;
* a tag whose value has the wrong count or a non-finite value is ignored and
  noted, never passed on as NaN.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# tag codes (DNG spec 1.7.1.0 chapter 4; TIFF/EP for the CFA tags)
TAG = {
    "CFARepeatPatternDim": 33421, "CFAPattern": 33422, "CFAPlaneColor": 50710,
    "CFALayout": 50711, "LinearizationTable": 50712, "BlackLevelRepeatDim": 50713,
    "BlackLevel": 50714, "BlackLevelDeltaH": 50715, "BlackLevelDeltaV": 50716,
    "WhiteLevel": 50717, "DefaultScale": 50718, "DefaultCropOrigin": 50719,
    "DefaultCropSize": 50720, "ColorMatrix1": 50721, "ColorMatrix2": 50722,
    "CameraCalibration1": 50723, "CameraCalibration2": 50724,
    "AnalogBalance": 50727, "AsShotNeutral": 50728, "AsShotWhiteXY": 50729,
    "BaselineExposure": 50730, "CalibrationIlluminant1": 50778,
    "CalibrationIlluminant2": 50779, "ActiveArea": 50829,
    "ForwardMatrix1": 50964, "ForwardMatrix2": 50965, "OpcodeList1": 51008,
    "OpcodeList2": 51009, "OpcodeList3": 51022, "NoiseProfile": 51041,
    "CalibrationIlluminant3": 52529, "CameraCalibration3": 52530,
    "ColorMatrix3": 52531, "ForwardMatrix3": 52532, "IlluminantData1": 52533,
    "IlluminantData2": 52534, "IlluminantData3": 52535,
    "DNGVersion": 50706, "UniqueCameraModel": 50708, "LensModel": 42036, "DNGPrivateData": 50740,
    "CameraSerialNumber": 50735,
    "Orientation": 274, "Make": 271, "Model": 272, "Software": 305,
    "ExposureTime": 33434, "FNumber": 33437, "ISOSpeedRatings": 34855,
    "FocalLength": 37386, "DateTimeOriginal": 36867,
    "FocalPlaneXResolution": 41486, "FocalPlaneYResolution": 41487,
    "FocalPlaneResolutionUnit": 41488,
    "ShadowScale": 50739, "ProfileHueSatMapDims": 50937, "ProfileHueSatMapData1": 50938,
    "ProfileHueSatMapData2": 50939, "ProfileToneCurve": 50940, "ProfileLookTableDims": 50981,
    "ProfileLookTableData": 50982, "ProfileHueSatMapEncoding": 51107,
    "ProfileLookTableEncoding": 51108, "BaselineExposureOffset": 51109,
    "DefaultBlackRender": 51110, "ProfileHueSatMapData3": 52537,
}

#: tags that belong to the raw IFD (the one holding the CFA or LinearRaw
#: image), as opposed to IFD0's camera-wide tags
RAW_IFD_TAGS = (
    "CFARepeatPatternDim", "CFAPattern", "CFAPlaneColor", "LinearizationTable",
    "BlackLevelRepeatDim", "BlackLevel", "BlackLevelDeltaH", "BlackLevelDeltaV",
    "WhiteLevel", "DefaultCropOrigin", "DefaultCropSize", "ActiveArea",
    "OpcodeList1", "OpcodeList2", "OpcodeList3", "NoiseProfile",
)


RATIONAL_TYPES = (5, 10)  # TIFF RATIONAL, SRATIONAL


def tag_dict(page) -> dict[int, tuple[int, Any]]:
    """{tag code: (TIFF type, value)} of one tifffile page."""
    out = {}
    for tag in page.tags.values():
        try:
            out[tag.code] = (int(tag.dtype), tag.value)
        except Exception:  # a tag tifffile cannot decode is treated as absent
            continue
    return out


class TagReader:
    """Typed access to the tags of the raw IFD, falling back to IFD0.

    Every accessor returns ``None`` for an absent or unusable tag and appends
    a one-line note when it had to decide something.
    """

    def __init__(self, raw_tags: dict[int, tuple[int, Any]], ifd0_tags: dict[int, tuple[int, Any]]):
        self.raw = raw_tags
        self.ifd0 = ifd0_tags
        self.notes: list[str] = []

    def _entry(self, name: str) -> tuple[int, Any] | None:
        code = TAG[name]
        if name in RAW_IFD_TAGS and code in self.raw:
            return self.raw[code]
        if code in self.ifd0:
            return self.ifd0[code]
        return self.raw.get(code)

    def get(self, name: str):
        """The tag's value as tifffile decoded it, or None."""
        e = self._entry(name)
        return None if e is None else e[1]

    def is_rational(self, name: str) -> bool:
        e = self._entry(name)
        return e is not None and e[0] in RATIONAL_TYPES

    def has(self, name: str) -> bool:
        return self.get(name) is not None

    # -- scalar helpers ---------------------------------------------------
    def numbers(self, name: str, count: int | None = None) -> tuple[float, ...] | None:
        """Tag as a tuple of floats (rationals divided out); None if absent,
        of the wrong count, or non-finite (noted)."""
        v = self.get(name)
        if v is None:
            return None
        vals = _as_numbers(v, rational=self.is_rational(name))
        if vals is None:
            self.notes.append(f"{name}: unreadable value {str(v)[:40]!r}, ignored")
            return None
        if not vals:
            self.notes.append(f"{name}: no values; ignored")
            return None
        if any(x is None for x in vals):
            self.notes.append(f"{name}: has a 0/0 rational, treated as absent")
            return None
        if not all(math.isfinite(x) for x in vals):
            self.notes.append(f"{name}: non-finite value, ignored")
            return None
        if count is not None and len(vals) != count:
            self.notes.append(f"{name}: expected {count} values, found {len(vals)}; ignored")
            return None
        return tuple(vals)

    def number(self, name: str) -> float | None:
        vals = self.numbers(name)
        if vals is None:
            return None
        if len(vals) != 1:
            self.notes.append(f"{name}: expected 1 value, found {len(vals)}; used the first")
        return vals[0] if vals else None

    def integer(self, name: str) -> int | None:
        v = self.get(name)
        if v is None:
            return None
        try:
            if isinstance(v, (tuple, list)):
                v = v[0]
            return int(v)
        except (TypeError, ValueError, IndexError):
            self.notes.append(f"{name}: not an integer ({str(v)[:40]!r}); ignored")
            return None

    def text(self, name: str) -> str:
        v = self.get(name)
        if v is None:
            return ""
        if isinstance(v, bytes):
            v = v.decode("latin-1", "replace")
        return str(v).strip("\x00 ").strip()

    def matrix(self, name: str) -> np.ndarray | None:
        """A 3×3 matrix tag (ColorMatrix, ForwardMatrix: 3 colour planes)."""
        vals = self.numbers(name)
        if vals is None:
            return None
        if len(vals) != 9:
            self.notes.append(f"{name}: {len(vals)} values, only 3-colour (9-value) matrices "
                              "are supported; ignored")
            return None
        m = np.array(vals, dtype=np.float64).reshape(3, 3)
        if np.abs(m).max() > 1e3:
            self.notes.append(f"{name}: implausible entries (|x| up to {np.abs(m).max():.3g}); ignored")
            return None
        if abs(np.linalg.det(m)) < 1e-12:
            self.notes.append(f"{name}: singular matrix; ignored")
            return None
        return m

    def blob(self, name: str) -> bytes | None:
        v = self.get(name)
        if v is None:
            return None
        if isinstance(v, np.ndarray):
            return v.tobytes()
        if isinstance(v, (bytes, bytearray)):
            return bytes(v)
        if isinstance(v, (tuple, list)):
            try:
                return bytes(int(x) & 0xFF for x in v)
            except (TypeError, ValueError):
                return None
        return None

    def array(self, name: str) -> np.ndarray | None:
        v = self.get(name)
        if v is None:
            return None
        vals = _as_numbers(v, rational=self.is_rational(name))
        if vals is None or any(x is None for x in vals):
            self.notes.append(f"{name}: unreadable; ignored")
            return None
        a = np.asarray(vals, dtype=np.float64)
        if not np.all(np.isfinite(a)):
            self.notes.append(f"{name}: non-finite values; ignored")
            return None
        return a


def _as_numbers(v, rational: bool) -> list | None:
    """Flatten a tifffile value to numbers; rationals (num, den) pairs are
    divided, with None for a zero denominator."""
    if isinstance(v, (bytes, bytearray, str)):
        return None
    if isinstance(v, np.ndarray):
        v = v.ravel().tolist()
    if not isinstance(v, (tuple, list)):
        v = [v]
    try:
        flat = [float(x) for x in v]
    except (TypeError, ValueError):
        return None
    # tifffile returns RATIONAL/SRATIONAL as flat (num, den, ...) sequences
    if rational:
        if len(flat) % 2:
            return None
        return [None if den == 0 else num / den for num, den in zip(flat[0::2], flat[1::2])]
    return flat


def profile_fields(r: TagReader) -> dict[str, Any]:
    """The camera profile's rendering tags as :class:`~isp.meta.CameraMeta`
    fields (``profile_*``, ``baseline_exposure_offset``,
    ``default_black_render``, ``shadow_scale``); a malformed tag is left out
    with a note on ``r``.

    Follows DNG 1.7.1.0 chapter 4 and the SDK's reader
    (``dng_camera_profile_info::ParseTag``, ``dng_camera_profile::Parse``):
    ProfileHueSatMapDims holds hues, sats and optionally vals (absent or 0
    means 1); a table's data holds ``hues · sats · vals`` triplets, or
    ``hues · (sats − 1) · vals`` when the zero-saturation column is left
    out; ProfileToneCurve holds (x, y) pairs, at least two, x increasing,
    all in [0, 1]; the encodings are 0 (linear) or 1 (sRGB).
    """
    out: dict[str, Any] = {}
    for dims_tag, data_tags, key in (
            ("ProfileHueSatMapDims", ("ProfileHueSatMapData1", "ProfileHueSatMapData2",
                                      "ProfileHueSatMapData3"), "profile_hue_sat_map"),
            ("ProfileLookTableDims", ("ProfileLookTableData",), "profile_look_table")):
        present = [t for t in data_tags if r.has(t)]
        if not present:
            continue
        dims = r.numbers(dims_tag)
        if dims is None or len(dims) not in (2, 3) or any(d != int(d) for d in dims):
            r.notes.append(f"{dims_tag} missing or malformed ({dims}); {', '.join(present)} ignored")
            continue
        hues, sats = int(dims[0]), int(dims[1])
        vals = int(dims[2]) if len(dims) == 3 and int(dims[2]) > 0 else 1
        if hues < 1 or sats < 2 or hues * sats * vals > 1 << 20:
            r.notes.append(f"{dims_tag} {hues}x{sats}x{vals} is not a usable table size; "
                           f"{', '.join(present)} ignored")
            continue
        kept = 0
        for i, tag in enumerate(data_tags):
            data = r.array(tag) if tag in present else None
            if data is None:
                continue
            if data.size not in (hues * sats * vals * 3, hues * (sats - 1) * vals * 3):
                r.notes.append(f"{tag} has {data.size} values for {hues}x{sats}x{vals} "
                               "triplets; ignored")
                continue
            field = f"{key}_data" if len(data_tags) == 1 else f"{key}_data_{i + 1}"
            out[field] = data.astype(np.float32)
            kept += 1
        if kept:
            out[f"{key}_dims"] = (hues, sats, vals)
    for tag, key in (("ProfileHueSatMapEncoding", "profile_hue_sat_map_encoding"),
                     ("ProfileLookTableEncoding", "profile_look_table_encoding")):
        code = r.integer(tag)
        if code is None:
            continue
        if code not in (0, 1):
            r.notes.append(f"{tag} {code} is not 0 (linear) or 1 (sRGB); linear used")
            continue
        out[key] = code
    curve = r.array("ProfileToneCurve")
    if curve is not None:
        pts = curve.reshape(-1, 2) if curve.size % 2 == 0 else None
        if (pts is None or pts.shape[0] < 2 or pts.min() < 0 or pts.max() > 1
                or np.any(np.diff(pts[:, 0]) <= 0)):
            r.notes.append(f"ProfileToneCurve with {curve.size} values is not a valid curve "
                           "(pairs in [0, 1], x increasing); the default curve is used")
        else:
            out["profile_tone_curve"] = pts
    offset = r.number("BaselineExposureOffset")
    if offset is not None:
        if abs(offset) > 16:
            r.notes.append(f"BaselineExposureOffset {offset:g} EV is outside ±16 EV; ignored")
        else:
            out["baseline_exposure_offset"] = offset
    black = r.integer("DefaultBlackRender")
    if black is not None:
        if black in (0, 1):
            out["default_black_render"] = black
        else:
            r.notes.append(f"DefaultBlackRender {black} is not 0 (auto) or 1 (none); ignored")
    scale = r.number("ShadowScale")
    if scale is not None:
        if 0 < scale <= 10:
            out["shadow_scale"] = scale
        else:
            r.notes.append(f"ShadowScale {scale:g} is outside (0, 10]; ignored")
    return out
