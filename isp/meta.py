"""Camera metadata: what a raw file says about the sensor, its colour and its
optics.

Field names follow the DNG specification (Adobe, *Digital Negative
Specification* 1.7.1.0, 2023), chapter 4 (tags) and chapter 6 (mapping
camera colour space to CIE XYZ). Absent tags are ``None``; a tag that was
present but unusable (a 0/0 BaselineExposure, a ColorMatrix without
CalibrationIlluminant, ...) is also ``None`` or defaulted, and the decision is
recorded in :attr:`CameraMeta.notes` so that ``isp info`` can report it.

Units
-----
=========================  ===========================================
field                      unit / domain
=========================  ===========================================
black_level                sensor DN, per CFA position (R, C, S)
white_level                sensor DN, per sample
baseline_exposure          EV (stops)
baseline_exposure_offset   EV (stops), the profile's, added to it
noise_profile              ((S, O), ...) per plane, on data scaled 0..1:
                           variance = S·x + O
pixel_pitch_um             µm
focal_length_mm            mm
origin                     (row, col) of data[0, 0] in active-area pixels
=========================  ===========================================
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from isp.frame import CFA

#: EXIF LightSource codes used by CalibrationIlluminant1/2 (DNG spec 4.x,
#: EXIF 2.32 table 6). 255 = "other" (DNG 1.6 IlluminantData).
LIGHT_SOURCES = {
    0: "Unknown", 1: "Daylight", 2: "Fluorescent", 3: "Tungsten", 4: "Flash",
    9: "Fine weather", 10: "Cloudy weather", 11: "Shade",
    12: "Daylight fluorescent", 13: "Day white fluorescent",
    14: "Cool white fluorescent", 15: "White fluorescent",
    16: "Warm white fluorescent", 17: "Standard light A", 18: "Standard light B",
    19: "Standard light C", 20: "D55", 21: "D65", 22: "D75", 23: "D50",
    24: "ISO studio tungsten", 255: "Other",
}

ORIENTATIONS = {
    1: "normal", 2: "mirrored horizontally", 3: "rotated 180°",
    4: "mirrored vertically", 5: "mirrored horizontally, rotated 270° CW",
    6: "rotated 90° CW", 7: "mirrored horizontally, rotated 90° CW",
    8: "rotated 270° CW",
}


@dataclass(frozen=True, eq=False)
class CameraMeta:
    """Everything the pipeline knows about a capture, besides its pixels.

    Matrices are (3, 3) float64 arrays in the DNG convention:
    ``color_matrix_*`` maps CIE XYZ to *reference* camera space,
    ``forward_matrix_*`` maps white-balanced camera space to XYZ D50,
    ``camera_calibration_*`` maps reference to individual camera space.
    """

    path: str | None = None
    make: str = ""
    model: str = ""
    unique_camera_model: str = ""
    #: the camera's own serial number (DNG CameraSerialNumber, else EXIF BodySerialNumber): on a
    #: production line, the module's identity; "" where the file names none
    serial: str = ""
    software: str = ""

    # geometry
    cfa: CFA | None = None                 # None: linear (demosaiced) data
    raw_size: tuple[int, int] = (0, 0)     # (H, W) as stored in the file
    active_area: tuple[int, int, int, int] | None = None  # top, left, bottom, right
    default_crop: tuple[int, int, int, int] | None = None  # x, y, w, h (active-area px)
    origin: tuple[int, int] = (0, 0)       # data[0, 0] in active-area coordinates
    orientation: int = 1                   # EXIF/TIFF Orientation 1..8
    bits_per_sample: int = 16

    # levels and linearisation
    black_level: np.ndarray = field(default_factory=lambda: np.zeros((1, 1, 1)))
    black_level_delta_h: np.ndarray | None = None  # per column of the active area
    black_level_delta_v: np.ndarray | None = None  # per row of the active area
    white_level: tuple[float, ...] = (65535.0,)
    linearization_table: np.ndarray | None = None
    #: linearisation steps the decoder (LibRaw) already applied to the pixels,
    #: e.g. ("LinearizationTable",) or ("OpcodeList2 MapPolynomial",)
    applied_by_decoder: tuple[str, ...] = ()

    # colour
    as_shot_neutral: tuple[float, float, float] | None = None
    as_shot_white_xy: tuple[float, float] | None = None
    analog_balance: tuple[float, float, float] | None = None
    color_matrix_1: np.ndarray | None = None
    color_matrix_2: np.ndarray | None = None
    color_matrix_3: np.ndarray | None = None
    forward_matrix_1: np.ndarray | None = None
    forward_matrix_2: np.ndarray | None = None
    forward_matrix_3: np.ndarray | None = None
    camera_calibration_1: np.ndarray | None = None
    camera_calibration_2: np.ndarray | None = None
    camera_calibration_3: np.ndarray | None = None
    calibration_illuminant_1: int | None = None
    calibration_illuminant_2: int | None = None
    calibration_illuminant_3: int | None = None
    illuminant_data_3: tuple[float, float] | None = None  # xy of illuminant 3 (DNG 1.6)

    # camera profile: rendering tables and defaults (DNG 1.7.1.0 chapter 4)
    #: (hues, sats, vals) of ProfileHueSatMapData1/2/3 (vals 1: a 2.5-D table)
    profile_hue_sat_map_dims: tuple[int, int, int] | None = None
    #: flat float32 (hue shift °, saturation scale, value scale) triplets,
    #: value outermost, then hue, saturation innermost
    profile_hue_sat_map_data_1: np.ndarray | None = None
    profile_hue_sat_map_data_2: np.ndarray | None = None
    profile_hue_sat_map_data_3: np.ndarray | None = None
    profile_hue_sat_map_encoding: int = 0  # 0 linear, 1 sRGB (value axis)
    profile_look_table_dims: tuple[int, int, int] | None = None
    profile_look_table_data: np.ndarray | None = None
    profile_look_table_encoding: int = 0   # 0 linear, 1 sRGB (value axis)
    profile_tone_curve: np.ndarray | None = None  # (N, 2) points (x, y) in [0, 1]
    baseline_exposure_offset: float | None = None  # EV, added to BaselineExposure
    default_black_render: int | None = None  # 0 auto, 1 none (no shadows black point)
    shadow_scale: float | None = None

    # exposure and noise
    baseline_exposure: float | None = None
    noise_profile: tuple[tuple[float, float], ...] | None = None

    # opcodes, keyed 1, 2, 3 (OpcodeList1/2/3)
    opcodes: dict[int, tuple] = field(default_factory=dict)

    # optics and capture
    pixel_pitch_um: float | None = None
    focal_length_mm: float | None = None
    f_number: float | None = None
    lens: str = ""
    exposure_time_s: float | None = None
    iso: float | None = None
    datetime: str = ""
    exif: dict[str, Any] = field(default_factory=dict)
    #: the camera module's calibration (``device/v1`` JSON text) the file carries in
    #: DNGPrivateData (:mod:`isp.io.device`); "" where it carries none
    device_calibration: str = ""

    #: what the reader decided on the user's behalf (one line each)
    notes: tuple[str, ...] = ()

    def replace(self, **changes) -> "CameraMeta":
        """A copy with ``changes`` applied."""
        return dataclasses.replace(self, **changes)

    @property
    def linear_raw(self) -> bool:
        """True for a linear (already demosaiced) DNG."""
        return self.cfa is None

    @property
    def active_size(self) -> tuple[int, int]:
        """(H, W) of the active area, the frame of reference for opcodes,
        lens shading and field position."""
        if self.active_area is not None:
            t, l, b, r = self.active_area
            return (b - t, r - l)
        return self.raw_size

    def black_pattern(self) -> np.ndarray:
        """BlackLevel repeat pattern (R, C, S) in DN, rolled so that
        element [0, 0] applies to ``data[0, 0]`` of a frame whose first pixel
        sits at :attr:`origin` (DNG spec, BlackLevel / BlackLevelRepeatDim).
        BlackLevelDeltaH/V are separate (``black_level_delta_*``)."""
        bl = np.asarray(self.black_level, dtype=np.float64)
        oy, ox = self.origin
        return np.roll(bl, shift=(-oy % bl.shape[0], -ox % bl.shape[1]), axis=(0, 1))

    def summary(self) -> dict[str, Any]:
        """A JSON-ready dictionary of the metadata (arrays as lists, opcode
        lists summarised)."""
        def conv(v):
            if isinstance(v, np.ndarray):
                if v.size > 64:
                    return {"shape": list(v.shape), "min": float(v.min()), "max": float(v.max())}
                return v.tolist()
            if isinstance(v, CFA):
                return v.value
            if isinstance(v, tuple):
                return [conv(x) for x in v]
            if isinstance(v, dict):
                return {str(k): conv(x) for k, x in v.items()}
            if isinstance(v, (np.floating, np.integer)):
                return v.item()
            return v

        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "opcodes":
                out[f.name] = {f"OpcodeList{k}": [op.describe() for op in ops] for k, ops in v.items()}
            elif f.name == "device_calibration":
                out[f.name] = _calibration_summary(v)
            else:
                out[f.name] = conv(v)
        for k in ("calibration_illuminant_1", "calibration_illuminant_2", "calibration_illuminant_3"):
            code = getattr(self, k)
            if code is not None:
                out[k + "_name"] = LIGHT_SOURCES.get(code, f"code {code}")
        out["orientation_name"] = ORIENTATIONS.get(self.orientation, "invalid")
        return out


def _calibration_summary(text: str) -> dict[str, Any] | None:
    """What ``isp info`` shows of a carried ``device/v1`` calibration: its
    lens, basis, grid, components, fit and source, not the numbers (None
    without one)."""
    if not text:
        return None
    import json

    try:
        d = json.loads(text)
    except ValueError:
        return {"error": "DNGPrivateData names a device/v1 calibration that is not JSON"}
    if not isinstance(d, dict):
        return {"error": "DNGPrivateData names a device/v1 calibration that is not a JSON object"}
    return {k: d.get(k) for k in ("format", "lens", "basis", "grid", "components", "fit", "source", "effects")}
