"""The DNG colour model: camera RGB → CIE XYZ (D50) → linear sRGB (D65).

The maths the ``ccm`` stage (:mod:`modules.ccm`) applies, and that white
balance and luminance use as well:

1. camera RGB → CIE XYZ (D50), the *profile connection space* (PCS) of the
   DNG specification, from the file's ColorMatrix / ForwardMatrix tags
   interpolated between the two calibration illuminants by the scene's
   correlated colour temperature, with the conversions between a white
   chromaticity (xy) and a camera neutral that the interpolation needs;
2. XYZ (D50) → linear sRGB (D65): Bradford chromatic adaptation D50 → D65,
   then the sRGB primaries;
3. for Adobe's render (:mod:`modules.dng_render`), camera RGB → linear
   ProPhoto RGB, the SDK's working space (:func:`camera_to_prophoto`, with
   the camera white where each channel clips), and ProPhoto → linear sRGB
   through the PCS with the SDK's published colorants
   (:func:`matrix_prophoto_to_srgb`).

Step 1 follows the *Adobe DNG Specification* 1.7.1.0, chapter 6, "Mapping
Camera Color Space to CIE XYZ Space", and, where the specification leaves a
choice open (normalisations, iteration limits, what happens with one matrix),
the reference implementation, the Adobe DNG SDK (``dng_color_spec.cpp``,
``dng_camera_profile.cpp``, ``dng_temperature.cpp``, ``dng_render.cpp``).

The model
---------
With ``AB = diag(AnalogBalance)``, ``CC`` = CameraCalibration (identity when
absent), ``CM`` = ColorMatrix, ``FM`` = ForwardMatrix, all interpolated
between calibrations 1 and 2 with the weight ``g`` of calibration 1:

=====================================  ======================================
step                                   equation (DNG 1.7.1.0, chapter 6)
=====================================  ======================================
weight of calibration 1                ``g = (1/T - 1/T2) / (1/T1 - 1/T2)``,
                                       clamped to [0, 1] ("inverse CCT")
XYZ to camera                          ``XYZtoCamera = AB·CC·CM``
white xy from a camera neutral         iterate ``xy ← xy(XYZtoCamera(xy)⁻¹·n)``
                                       from D50 ("Translating Camera Neutral
                                       Coordinates to White Balance xy")
camera neutral from a white xy         ``n = XYZtoCamera(xy)·XYZ(xy)``,
                                       scaled to max 1 ("Translating White
                                       Balance xy Coordinates to Camera
                                       Neutral Coordinates")
with ForwardMatrix                     ``CameraToXYZ_D50 = FM·D·(AB·CC)⁻¹``,
                                       ``D = diag((AB·CC)⁻¹·n)⁻¹``
without ForwardMatrix                  ``CameraToXYZ_D50 = CA·XYZtoCamera⁻¹``,
                                       CA = Bradford white → D50
=====================================  ======================================

The normalisations (all from the SDK; the specification states the intent):

* ``ColorMatrix`` is scaled so that ``max(CM·XYZ_D50) = 1`` when it is off by
  more than 1 % (``dng_camera_profile::NormalizeColorMatrix``). The result is
  scale-free except for the interpolation, which mixes two matrices and so
  needs them on the same scale.
* ``ForwardMatrix`` rows are scaled so that ``FM·(1, 1, 1) = XYZ_D50``
  exactly (``dng_camera_profile::NormalizeForwardMatrix``).
* The camera neutral is scaled so that its largest entry is 1 and pinned to
  [0.001, 1] (``dng_color_spec::SetWhiteXY``).
* Without ForwardMatrix, ``CameraToXYZ_D50`` is scaled so that this camera
  neutral maps to ``Y = 1`` ("scale matrix so PCS white can just be reached
  when the first camera channel saturates", ``dng_color_spec::SetWhiteXY``).
  With ForwardMatrix the same holds by construction. So in both paths the
  camera neutral with maximum 1 maps to the D50 white ``(0.9643, 1, 0.8251)``.

The SDK also rounds profile matrices to four decimals when it reads them
(``SetColorMatrix1`` etc.); that is storage quantisation, not colour science,
and is not done here (it moves an element by at most 5e-5).

What this module does not do: triple-illuminant profiles (DNG 1.6
ColorMatrix3; ignored with a note), ReductionMatrix (four-colour sensors are
refused at the reader), HueSatMap / LookTable and ProfileToneCurve (rendering
choices, not colour mapping: :mod:`modules.common.dng_profile` and
:mod:`modules.common.dng_tone`), and CameraCalibrationSignature matching
(CameraCalibration is always used when present, as the SDK does when the
signatures agree or are both absent).

Domains
-------
==================  ===============================  ======================
quantity            convention                       range
==================  ===============================  ======================
camera RGB          linear, unbalanced unless said   [0, ∞), white ≈ 1
balanced camera     camera RGB / applied neutral     [0, ∞)
XYZ (D50)           CIE 1931 XYZ, white Y = 1        [0, ∞)
linear sRGB         IEC 61966-2-1 primaries, D65,    unbounded (no clipping)
                    white (1, 1, 1)
xy                  CIE 1931 chromaticity            [0, 1]
CCT                 kelvin                           (1667, ∞)
==================  ===============================  ======================

References
----------
* Adobe Inc. *Digital Negative (DNG) Specification*, version 1.7.1.0
  (2023), chapter 6 "Mapping Camera Color Space to CIE XYZ Space"; chapter 4
  tags ColorMatrix1/2, CameraCalibration1/2, AnalogBalance, AsShotNeutral,
  AsShotWhiteXY, CalibrationIlluminant1/2, ForwardMatrix1/2.
* Adobe DNG SDK 1.7: ``dng_color_spec.cpp`` (FindXYZtoCamera, SetWhiteXY,
  NeutralToXY, MapWhiteMatrix), ``dng_camera_profile.cpp``
  (IlluminantToTemperature, NormalizeColorMatrix, NormalizeForwardMatrix),
  ``dng_render.cpp`` (default white D55), ``dng_xy_coord.h`` (D50 =
  (0.3457, 0.3585)).
* Robertson, A. R. (1968). Computation of correlated color temperature and
  distribution temperature. *J. Opt. Soc. Am.* 58(11), 1528–1535.
* Lam, K. M. (1985). *Metamerism and colour constancy* (PhD thesis,
  University of Bradford) — the Bradford transform; Lindbloom, B.
  "Chromatic Adaptation" (brucelindbloom.com) for its published matrices.
* IEC 61966-2-1:1999 *Default RGB colour space — sRGB*.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.errors import InputError
from isp.meta import LIGHT_SOURCES, CameraMeta

__all__ = [
    "ILLUMINANT_CCT",
    "PCS_WHITE_XY",
    "PROPHOTO_TO_XYZ_D50",
    "SOURCES",
    "SRGB_TO_XYZ_D50",
    "bradford_matrix",
    "camera_neutral_to_xy",
    "camera_to_linear_srgb",
    "camera_to_prophoto",
    "camera_to_xyz_d50",
    "check_source",
    "illuminant_to_cct",
    "interpolation_weight",
    "matrix_prophoto_to_srgb",
    "matrix_xyz_d50_to_linear_srgb",
    "matrix_xyz_d50_to_prophoto",
    "normalize_color_matrix",
    "normalize_forward_matrix",
    "rgb_to_pcs_matrix",
    "xy_to_camera_neutral",
    "xy_to_cct",
    "xy_to_xyz",
    "xyz_to_xy",
]

#: White of the profile connection space, CIE 1931 xy of D50 as the DNG SDK
#: fixes it (``dng_xy_coord.h``, ``D50_xy_coord``).
PCS_WHITE_XY = (0.3457, 0.3585)

#: White the SDK renders with when a file has neither AsShotNeutral nor
#: AsShotWhiteXY (``dng_render.cpp``; ``D55_xy_coord``).
DEFAULT_WHITE_XY = (0.3324, 0.3474)

#: ROMM RGB (ProPhoto RGB) → CIE XYZ (D50), the working space of Adobe's
#: renderer (ISO 22028-2:2013 / ANSI/I3A IT10.7666:2003; the DNG SDK's
#: ``dng_space_ProPhoto``). Rows are rescaled by :func:`rgb_to_pcs_matrix`.
PROPHOTO_TO_XYZ_D50 = ((0.7977, 0.1352, 0.0313),
                       (0.2880, 0.7119, 0.0001),
                       (0.0000, 0.0000, 0.8249))

#: sRGB → CIE XYZ (D50): the sRGB primaries Bradford-adapted to D50, four
#: decimals, as the ICC sRGB profile's colorants and the DNG SDK's
#: ``dng_space_sRGB`` state them. Rows are rescaled by :func:`rgb_to_pcs_matrix`.
SRGB_TO_XYZ_D50 = ((0.4361, 0.3851, 0.1431),
                   (0.2225, 0.7169, 0.0606),
                   (0.0139, 0.0971, 0.7141))

#: The Bradford cone-response matrix (Lam 1985, as Lindbloom publishes it
#: and the SDK's ``MapWhiteMatrix`` uses it): XYZ → sharpened cone RGB.
BRADFORD = ((0.8951, 0.2664, -0.1614),
            (-0.7502, 1.7135, 0.0367),
            (0.0389, -0.0685, 1.0296))

#: sRGB primaries (red, green, blue) and white, CIE 1931 xy
#: (IEC 61966-2-1:1999, clause 5.1; the white is D65).
SRGB_PRIMARIES_XY = ((0.64, 0.33), (0.30, 0.60), (0.15, 0.06))
SRGB_WHITE_XY = (0.3127, 0.3290)

# Robertson's (1968) isotemperature lines: reciprocal temperature (mired),
# the Planckian point (u, v) in CIE 1960 UCS and the slope t of the line, as
# Wyszecki & Stiles (1982) tabulate them. The 325-mired u is 0.24792, the
# correction Lindbloom publishes of the table's misprinted 0.24702 (which
# the SDK's ``dng_temperature`` keeps): the two differ only for whites
# between the 300- and 350-mired lines, by up to 4.4 mired.
_ROBERTSON = np.array((
    (0, 0.18006, 0.26352, -0.24341), (10, 0.18066, 0.26589, -0.25479),
    (20, 0.18133, 0.26846, -0.26876), (30, 0.18208, 0.27119, -0.28539),
    (40, 0.18293, 0.27407, -0.30470), (50, 0.18388, 0.27709, -0.32675),
    (60, 0.18494, 0.28021, -0.35156), (70, 0.18611, 0.28342, -0.37915),
    (80, 0.18740, 0.28668, -0.40955), (90, 0.18880, 0.28997, -0.44278),
    (100, 0.19032, 0.29326, -0.47888), (125, 0.19462, 0.30141, -0.58204),
    (150, 0.19962, 0.30921, -0.70471), (175, 0.20525, 0.31647, -0.84901),
    (200, 0.21142, 0.32312, -1.0182), (225, 0.21807, 0.32909, -1.2168),
    (250, 0.22511, 0.33439, -1.4512), (275, 0.23247, 0.33904, -1.7298),
    (300, 0.24010, 0.34308, -2.0637), (325, 0.24792, 0.34655, -2.4681),
    (350, 0.25591, 0.34951, -2.9641), (375, 0.26400, 0.35200, -3.5814),
    (400, 0.27218, 0.35407, -4.3633), (425, 0.28039, 0.35577, -5.3762),
    (450, 0.28863, 0.35714, -6.7262), (475, 0.29685, 0.35823, -8.5955),
    (500, 0.30505, 0.35907, -11.324), (525, 0.31320, 0.35968, -15.628),
    (550, 0.32129, 0.36011, -23.325), (575, 0.32931, 0.36038, -40.770),
    (600, 0.33724, 0.36051, -116.45)))

#: Correlated colour temperature (K) of each EXIF LightSource code used by
#: CalibrationIlluminant1/2, as ``dng_camera_profile::IlluminantToTemperature``
#: of DNG SDK 1.6/1.7 (fluorescent classes: midpoints of the EXIF 2.3 ranges).
#: 0 "Unknown" and codes not listed have no temperature; 255 "Other" takes
#: the temperature of its IlluminantData xy (see :func:`illuminant_to_cct`).
ILLUMINANT_CCT = {
    17: 2850.0, 3: 2850.0,                      # Standard light A, Tungsten
    24: 3200.0,                                 # ISO studio tungsten
    23: 5000.0,                                 # D50
    20: 5500.0, 1: 5500.0, 9: 5500.0, 4: 5500.0, 18: 5500.0,  # D55, Daylight,
                                                # Fine weather, Flash, Std B
    21: 6500.0, 19: 6500.0, 10: 6500.0,         # D65, Std C, Cloudy
    22: 7500.0, 11: 7500.0,                     # D75, Shade
    12: (5700.0 + 7100.0) / 2,                  # Daylight fluorescent
    13: (4600.0 + 5500.0) / 2,                  # Day white fluorescent
    14: (3800.0 + 4500.0) / 2, 2: (3800.0 + 4500.0) / 2,  # Cool white, Fluorescent
    15: (3250.0 + 3800.0) / 2,                  # White fluorescent
    16: (2600.0 + 3250.0) / 2,                  # Warm white fluorescent
}

#: Where the camera → XYZ matrix comes from, by name (``source=``).
SOURCES = {
    "auto": "ForwardMatrix when the profile has one, else ColorMatrix; "
            "interpolated between the calibrations by the scene CCT",
    "color_matrix": "ColorMatrix inverted and Bradford-adapted to D50; "
                    "forward matrices ignored; interpolated",
    "color_matrix_1": "ColorMatrix1 (with CameraCalibration1) alone, no interpolation",
    "color_matrix_2": "ColorMatrix2 (with CameraCalibration2) alone, no interpolation",
    "forward_matrix": "ForwardMatrix, interpolated; an error if the profile has none",
}

SourceName = Literal["auto", "color_matrix", "color_matrix_1", "color_matrix_2",
                     "forward_matrix"]

# NeutralToXY: passes and tolerance on |Δx| + |Δy| (dng_color_spec.cpp).
_NEUTRAL_TO_XY_PASSES = 30
_NEUTRAL_TO_XY_TOLERANCE = 1e-7


# --------------------------------------------------------------------------
# small numeric helpers

def check_source(source: str) -> str:
    """``source`` if it is one of :data:`SOURCES` (the colour models a
    stage may be asked for), else ValueError listing the valid names."""
    if source not in SOURCES:
        raise ValueError(f"unknown colour source {source!r}; valid: {', '.join(SOURCES)}")
    return source


def _as_matrix(m, label: str) -> np.ndarray:
    a = np.asarray(m, dtype=np.float64)
    if a.size != 9:
        raise ValueError(f"{label} must have 9 elements (3x3), got shape {a.shape}")
    a = a.reshape(3, 3)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{label} has non-finite elements: {a.tolist()}")
    return a


def _as_neutral(n, label: str) -> np.ndarray:
    a = np.asarray(n, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a <= 0):
        raise ValueError(f"{label} must be 3 positive finite numbers (R, G, B), got {n!r}")
    return a


def _as_xy(xy, label: str) -> np.ndarray:
    a = np.asarray(xy, dtype=np.float64).reshape(-1)
    if a.shape != (2,) or not np.all(np.isfinite(a)) or a[1] <= 0 or a.sum() >= 1 or np.any(a <= 0):
        raise ValueError(f"{label} must be a chromaticity (x, y) with x, y > 0 and x + y < 1, "
                         f"got {xy!r}")
    return a


def _pcs_xyz() -> np.ndarray:
    return xy_to_xyz(PCS_WHITE_XY)


def xy_to_xyz(xy) -> np.ndarray:
    """CIE XYZ with ``Y = 1`` of a chromaticity.

    Parameters
    ----------
    xy : (..., 2) array_like
        CIE 1931 chromaticity, ``y > 0``.

    Returns
    -------
    (..., 3) ndarray
        ``(x / y, 1, (1 - x - y) / y)``, float64.

    Examples
    --------
    >>> np.round(xy_to_xyz((0.3457, 0.3585)), 4).tolist()
    [0.9643, 1.0, 0.8251]
    """
    a = np.asarray(xy, dtype=np.float64)
    x, y = a[..., 0], a[..., 1]
    return np.stack([x / y, np.ones_like(x), (1.0 - x - y) / y], axis=-1)


def xyz_to_xy(xyz) -> np.ndarray:
    """CIE 1931 chromaticity of a CIE XYZ value.

    Parameters
    ----------
    xyz : (..., 3) array_like
        CIE XYZ, any scale, ``X + Y + Z != 0``.

    Returns
    -------
    (..., 2) ndarray
        ``(X, Y) / (X + Y + Z)``, float64.

    Examples
    --------
    >>> np.round(xyz_to_xy((0.95047, 1.0, 1.08883)), 4).tolist()
    [0.3127, 0.329]
    """
    a = np.asarray(xyz, dtype=np.float64)
    return a[..., :2] / a.sum(axis=-1, keepdims=True)


def _robertson_cct(u: float, v: float) -> float:
    """Robertson's (1968) method at one CIE 1960 (u, v): the CCT between
    the first isotemperature line the point lies below and the one before,
    weighted by the point's distances to the two (the SDK's
    ``dng_temperature::Set_xy_coord``)."""
    mired, lu, lv, slope = _ROBERTSON.T
    norm = np.hypot(1.0, slope)
    # signed distance of (u, v) from each line, along the line's normal
    dist = -(u - lu) * (slope / norm) + (v - lv) * (1.0 / norm)
    below = np.flatnonzero(dist[1:] <= 0.0)
    i = int(below[0]) + 1 if below.size else len(mired) - 1
    here = -min(dist[i], 0.0)
    f = 0.0 if i == 1 else here / (dist[i - 1] + here)
    r = mired[i - 1] * f + mired[i] * (1.0 - f)
    with np.errstate(divide="ignore"):
        return float(np.float64(1.0e6) / r)


def _fmt(v, digits: int = 4) -> str:
    return "(" + ", ".join(f"{float(x):.{digits}g}" for x in v) + ")"


def _light_name(code: int | None) -> str:
    if code is None:
        return "missing"
    return LIGHT_SOURCES.get(int(code), f"code {code}")


# --------------------------------------------------------------------------
# temperatures and weights

def xy_to_cct(xy) -> float:
    """Correlated colour temperature of a chromaticity, Robertson (1968).

    Parameters
    ----------
    xy : (2,) array_like
        CIE 1931 chromaticity.

    Returns
    -------
    float
        CCT in kelvin; ``inf`` beyond the bluest isotemperature line.

    Notes
    -----
    The chromaticity goes to CIE 1960 UCS, ``u = 4x / (-2x + 12y + 3)``,
    ``v = 6y / (-2x + 12y + 3)``, and Robertson's method interpolates between
    the two of its 31 isotemperature lines that bracket ``(u, v)`` — the same
    method as the SDK's ``dng_temperature``, with the table's 325-mired
    ``u`` as Lindbloom corrects it (0.24792; the SDK keeps the printed
    0.24702, which moves whites between 2860 K and 3330 K by up to 4.4
    mired). The tests check it against colour-science's
    ``uv_to_CCT_Robertson1968``.

    Examples
    --------
    >>> round(xy_to_cct((0.3127, 0.3290)))
    6504
    """
    x, y = np.asarray(xy, dtype=np.float64).reshape(2)
    d = -2.0 * x + 12.0 * y + 3.0
    return _robertson_cct(4.0 * x / d, 6.0 * y / d)


def illuminant_to_cct(code: int | None, xy=None) -> float | None:
    """Correlated colour temperature of a CalibrationIlluminant code.

    Parameters
    ----------
    code : int or None
        EXIF LightSource code (DNG CalibrationIlluminant1/2/3).
    xy : (2,) array_like, optional
        The illuminant's chromaticity from IlluminantData (DNG 1.6), used for
        code 255 "Other".

    Returns
    -------
    float or None
        CCT in kelvin; None for 0 "Unknown", a missing code, an unlisted
        code, or 255 without ``xy``.

    Notes
    -----
    The table :data:`ILLUMINANT_CCT` is the DNG SDK's
    ``IlluminantToTemperature`` (SDK 1.6/1.7): standard illuminants at their
    nominal CCT, fluorescent classes at the midpoint of their EXIF 2.3
    ranges, 255 via Robertson (1968) on its IlluminantData xy.

    Examples
    --------
    >>> illuminant_to_cct(21), illuminant_to_cct(17), illuminant_to_cct(0)
    (6500.0, 2850.0, None)
    """
    if code is None:
        return None
    code = int(code)
    if code == 255:
        return None if xy is None else xy_to_cct(_as_xy(xy, "IlluminantData xy"))
    return ILLUMINANT_CCT.get(code)


def interpolation_weight(cct: float, cct1: float, cct2: float) -> float:
    """Weight of calibration 1 for a scene at ``cct``, linear in inverse
    temperature (mired) and clamped.

    Parameters
    ----------
    cct : float
        Scene CCT in kelvin (> 0; ``inf`` allowed).
    cct1, cct2 : float
        CCTs of CalibrationIlluminant1 and 2 in kelvin (> 0), either order.

    Returns
    -------
    float
        ``g`` in [0, 1]; calibration 2 gets ``1 - g``. 1 when ``cct1 == cct2``.

    Notes
    -----
    DNG 1.7.1.0 chapter 6 interpolates the two calibrations linearly in
    inverse correlated colour temperature, and uses the nearer calibration
    outside [CCT1, CCT2] (``dng_color_spec::FindXYZtoCamera``):

    ``g = clip((1/T − 1/T2) / (1/T1 − 1/T2), 0, 1)``.

    Examples
    --------
    >>> interpolation_weight(2850, 2850, 6500), interpolation_weight(6500, 2850, 6500)
    (1.0, 0.0)
    >>> round(interpolation_weight(4000, 2850, 6500), 4)
    0.488
    """
    cct, cct1, cct2 = float(cct), float(cct1), float(cct2)
    if not (cct > 0 and cct1 > 0 and cct2 > 0) or math.isnan(cct):
        raise ValueError(f"temperatures must be positive kelvin, got cct={cct}, "
                         f"cct1={cct1}, cct2={cct2}")
    if cct1 == cct2:
        return 1.0
    g = (1.0 / cct - 1.0 / cct2) / (1.0 / cct1 - 1.0 / cct2)
    return float(min(1.0, max(0.0, g)))


# --------------------------------------------------------------------------
# normalisations and fixed matrices

def normalize_color_matrix(m) -> np.ndarray:
    """ColorMatrix scaled so that D50 white maps to a camera maximum of 1.

    Parameters
    ----------
    m : (3, 3) array_like
        ColorMatrix (XYZ → reference camera RGB).

    Returns
    -------
    (3, 3) ndarray, float64

    Notes
    -----
    ``dng_camera_profile::NormalizeColorMatrix``: with ``c = m·XYZ_D50`` and
    ``k = max(c)``, ``m / k`` when ``k > 0`` and ``k ∉ [0.99, 1.01]``, else
    ``m`` unchanged (the SDK's further rounding to 1e-4 is not done).

    Examples
    --------
    >>> m = normalize_color_matrix(2 * np.eye(3))
    >>> round(float((m @ xy_to_xyz(PCS_WHITE_XY)).max()), 6)
    1.0
    """
    m = _as_matrix(m, "ColorMatrix")
    k = float((m @ _pcs_xyz()).max())
    if k > 0.0 and (k < 0.99 or k > 1.01):
        m = m / k
    return m


def normalize_forward_matrix(m) -> np.ndarray:
    """ForwardMatrix with rows scaled so that camera (1, 1, 1) maps to D50.

    Parameters
    ----------
    m : (3, 3) array_like
        ForwardMatrix (white-balanced camera RGB → XYZ D50).

    Returns
    -------
    (3, 3) ndarray, float64

    Notes
    -----
    ``dng_camera_profile::NormalizeForwardMatrix``:
    ``FM' = diag(XYZ_D50) · diag(FM·1)⁻¹ · FM``, so ``FM'·1 = XYZ_D50`` with
    ``XYZ_D50`` from xy (0.3457, 0.3585), Y = 1.

    Examples
    --------
    >>> fm = normalize_forward_matrix(np.full((3, 3), 0.3))
    >>> np.round(fm @ np.ones(3), 4).tolist()
    [0.9643, 1.0, 0.8251]
    """
    m = _as_matrix(m, "ForwardMatrix")
    s = m @ np.ones(3)
    if np.any(s == 0):
        raise ValueError(f"ForwardMatrix maps camera white to zero: FM·1 = {s.tolist()}")
    return (_pcs_xyz() / s)[:, None] * m


def bradford_matrix(xyz_source_white, xyz_target_white) -> np.ndarray:
    """Bradford chromatic adaptation matrix (linearised, von Kries form).

    Parameters
    ----------
    xyz_source_white, xyz_target_white : (3,) array_like
        CIE XYZ of the adopted whites (any common scale, usually Y = 1).

    Returns
    -------
    (3, 3) ndarray
        ``M`` with ``XYZ_target = M · XYZ_source``.

    Notes
    -----
    ``M = B⁻¹ · diag(B·W_t / B·W_s) · B`` with the Bradford cone matrix ``B``
    (Lam 1985; the SDK's ``MapWhiteMatrix``), as colour-science's
    ``matrix_chromatic_adaptation_VonKries(..., "Bradford")`` (the tests
    compare the two). The SDK's
    guard clamping cone ratios to [0.1, 10] is not applied; it only acts on
    whites far outside any physical light.

    Examples
    --------
    >>> d50, d65 = [0.96422, 1.0, 0.82521], [0.95047, 1.0, 1.08883]
    >>> np.round(bradford_matrix(d50, d65)[0], 4).tolist()
    [0.9556, -0.023, 0.0632]
    """
    b = np.asarray(BRADFORD, dtype=np.float64)
    gain = (b @ np.asarray(xyz_target_white, dtype=np.float64)) / (b @ np.asarray(xyz_source_white, dtype=np.float64))
    return np.linalg.inv(b) @ (gain[:, None] * b)


def matrix_xyz_d50_to_linear_srgb() -> np.ndarray:
    """XYZ (D50, the DNG PCS) → linear sRGB (D65).

    Returns
    -------
    (3, 3) ndarray
        Maps the PCS white ``XYZ(0.3457, 0.3585)`` to sRGB (1, 1, 1).

    Notes
    -----
    ``M = NPM_sRGB⁻¹ · Bradford(D50 → D65)``, with ``NPM_sRGB`` the
    normalised primary matrix of the IEC 61966-2-1 primaries and the D65
    white xy (0.3127, 0.3290), derived rather than the standard's
    4-decimal rounded matrix so that white maps to white exactly.

    Examples
    --------
    >>> M = matrix_xyz_d50_to_linear_srgb()
    >>> np.round(M @ xy_to_xyz(PCS_WHITE_XY), 6).tolist()
    [1.0, 1.0, 1.0]
    """
    primaries = xy_to_xyz(SRGB_PRIMARIES_XY).T          # columns: XYZ of each primary, Y = 1
    white = xy_to_xyz(SRGB_WHITE_XY)
    npm = primaries * np.linalg.solve(primaries, white)  # scale each primary so R = G = B = 1 is the white
    cat = bradford_matrix(_pcs_xyz(), white)
    return np.linalg.inv(npm) @ cat


# --------------------------------------------------------------------------
# the colour specification of one file (the SDK's dng_color_spec)

@dataclass(frozen=True)
class _Calibration:
    index: int                      # 1 or 2: which tag set
    illuminant: int | None          # CalibrationIlluminant code
    cct: float | None               # K
    xyz_to_camera: np.ndarray       # AB·CC·CM (CM normalised)
    camera_calibration: np.ndarray  # CC (identity when absent)
    forward_matrix: np.ndarray | None  # normalised

    def describe(self) -> str:
        t = f", {self.cct:.0f} K" if self.cct else ""
        return f"calibration {self.index} ({_light_name(self.illuminant)}{t})"


@dataclass(frozen=True)
class _Interpolated:
    xyz_to_camera: np.ndarray
    camera_calibration: np.ndarray
    forward_matrix: np.ndarray | None
    weight: float            # of the first calibration
    cct: float               # K of the white


@dataclass(frozen=True)
class _Spec:
    calibrations: tuple      # of _Calibration: 1 (no interpolation) or 2
    analog_balance: np.ndarray
    use_forward: bool
    label: str               # which matrices, for notes
    notes: tuple

    def find(self, xy) -> _Interpolated:
        """FindXYZtoCamera: the matrices interpolated for white ``xy``."""
        cct = xy_to_cct(xy)
        if len(self.calibrations) == 1:
            c = self.calibrations[0]
            return _Interpolated(c.xyz_to_camera, c.camera_calibration, c.forward_matrix, 1.0, cct)
        c1, c2 = self.calibrations
        g = interpolation_weight(cct, c1.cct, c2.cct)
        fm1, fm2 = c1.forward_matrix, c2.forward_matrix
        if fm1 is not None and fm2 is not None:
            fm = g * fm1 + (1 - g) * fm2
        else:
            fm = fm1 if fm1 is not None else fm2
        return _Interpolated(g * c1.xyz_to_camera + (1 - g) * c2.xyz_to_camera,
                             g * c1.camera_calibration + (1 - g) * c2.camera_calibration,
                             fm, g, cct)

    def neutral_to_xy(self, neutral: np.ndarray) -> tuple[np.ndarray, str | None]:
        """NeutralToXY: fixed-point iteration from D50; a note if it did not
        converge."""
        last = np.asarray(PCS_WHITE_XY, dtype=np.float64)
        for npass in range(_NEUTRAL_TO_XY_PASSES):
            m = self.find(last).xyz_to_camera
            nxt = xyz_to_xy(np.linalg.solve(m, neutral))
            if np.abs(nxt - last).sum() < _NEUTRAL_TO_XY_TOLERANCE:
                return nxt, None
            if npass == _NEUTRAL_TO_XY_PASSES - 1:
                nxt = 0.5 * (last + nxt)
            last = nxt
        return last, (f"white xy did not converge in {_NEUTRAL_TO_XY_PASSES} passes: "
                      f"mean of the last two taken, as the DNG SDK")

    def camera_white(self, xy, found: _Interpolated | None = None) -> np.ndarray:
        """Camera neutral for white ``xy``, max 1, pinned to [0.001, 1]."""
        found = found or self.find(xy)
        n = found.xyz_to_camera @ xy_to_xyz(xy)
        return np.clip(n / n.max(), 0.001, 1.0)

    def camera_to_pcs(self, xy) -> tuple[np.ndarray, _Interpolated, bool]:
        """SetWhiteXY: CameraToPCS for white ``xy``; True when the forward
        matrix was used."""
        xy = np.asarray(xy, dtype=np.float64)
        found = self.find(xy)
        white = self.camera_white(xy, found)
        if self.use_forward and found.forward_matrix is not None:
            individual_to_reference = np.linalg.inv(np.diag(self.analog_balance)
                                                    @ found.camera_calibration)
            reference_white = individual_to_reference @ white
            m = found.forward_matrix @ np.diag(1.0 / reference_white) @ individual_to_reference
            return m, found, True
        pcs_to_camera = found.xyz_to_camera @ bradford_matrix(_pcs_xyz(), xy_to_xyz(xy))
        scale = float((pcs_to_camera @ _pcs_xyz()).max())
        if scale <= 0.0:
            scale = 1.0
        return np.linalg.inv(pcs_to_camera / scale), found, False


def _has_color_matrix(meta: CameraMeta) -> bool:
    return meta.color_matrix_1 is not None or meta.color_matrix_2 is not None


def _calibration(meta: CameraMeta, i: int, ab: np.ndarray) -> _Calibration:
    cm = normalize_color_matrix(_as_matrix(getattr(meta, f"color_matrix_{i}"), f"ColorMatrix{i}"))
    cc_tag = getattr(meta, f"camera_calibration_{i}")
    cc = np.eye(3) if cc_tag is None else _as_matrix(cc_tag, f"CameraCalibration{i}")
    fm_tag = getattr(meta, f"forward_matrix_{i}")
    fm = None if fm_tag is None else normalize_forward_matrix(fm_tag)
    code = getattr(meta, f"calibration_illuminant_{i}")
    cct = illuminant_to_cct(code, getattr(meta, f"illuminant_data_{i}", None))
    return _Calibration(i, code, cct, np.diag(ab) @ cc @ cm, cc, fm)


def _build_spec(meta: CameraMeta, source: str) -> _Spec:
    """The colour specification for ``source`` (the SDK's dng_color_spec
    constructor). Raises InputError when the requested tags are missing."""
    check_source(source)
    if not _has_color_matrix(meta):
        raise InputError(meta.path, "no ColorMatrix1/2: camera colour cannot be mapped to XYZ")
    ab = (np.ones(3) if meta.analog_balance is None
          else _as_neutral(meta.analog_balance, "AnalogBalance"))
    notes = []
    if meta.color_matrix_3 is not None:
        notes.append("ColorMatrix3 ignored: triple-illuminant profiles (DNG 1.6) not implemented")

    if source in ("color_matrix_1", "color_matrix_2"):
        i = int(source[-1])
        if getattr(meta, f"color_matrix_{i}") is None:
            raise InputError(meta.path, f"source {source!r}: the file has no ColorMatrix{i}; "
                                        f"use source='auto' or 'color_matrix'")
        cal = _calibration(meta, i, ab)
        return _Spec((cal,), ab, False, f"ColorMatrix{i} alone (source {source!r}), "
                                        "no interpolation", tuple(notes))

    present = [i for i in (1, 2) if getattr(meta, f"color_matrix_{i}") is not None]
    cals = [_calibration(meta, i, ab) for i in present]
    if len(cals) == 2:
        c1, c2 = cals
        if c1.cct and c2.cct and c1.cct != c2.cct:
            label = "interpolated"
        else:
            why = []
            for c in cals:
                if not c.cct:
                    why.append(f"CalibrationIlluminant{c.index} "
                               f"{'missing' if c.illuminant is None else _light_name(c.illuminant)}"
                               " has no temperature")
            if not why:
                why.append(f"both calibrations at {c1.cct:.0f} K")
            # The SDK keeps calibration 1 when it cannot interpolate.
            cals = [c1]
            label = "ColorMatrix1 alone, no interpolation (" + "; ".join(why) + ")"
    else:
        c = cals[0]
        label = f"ColorMatrix{c.index} alone, no interpolation (the file has one ColorMatrix"
        if not c.cct:
            label += f"; CalibrationIlluminant{c.index} " + (
                "missing" if c.illuminant is None else f"{_light_name(c.illuminant)}, no temperature")
        label += ")"

    has_fm = any(c.forward_matrix is not None for c in cals)
    if source == "forward_matrix" and not has_fm:
        raise InputError(meta.path, "source 'forward_matrix': the profile has no ForwardMatrix; "
                                    "use source='auto' or 'color_matrix'")
    use_forward = has_fm and source in ("auto", "forward_matrix")
    return _Spec(tuple(cals), ab, use_forward, label, tuple(notes))


# --------------------------------------------------------------------------
# public conversions

def camera_neutral_to_xy(meta: CameraMeta, neutral, source: SourceName = "auto") -> np.ndarray:
    """White-balance chromaticity of a camera neutral.

    Parameters
    ----------
    meta : CameraMeta
        ColorMatrix1/2, CameraCalibration1/2, AnalogBalance,
        CalibrationIlluminant1/2 are used.
    neutral : (3,) array_like
        Camera neutral (R, G, B), positive, any scale (AsShotNeutral).
    source : str
        See :data:`SOURCES`; only the choice of colour matrices matters here.

    Returns
    -------
    (2,) ndarray
        CIE 1931 xy of the scene white.

    Notes
    -----
    DNG 1.7.1.0 chapter 6, "Translating Camera Neutral Coordinates to White
    Balance xy Coordinates": an iteration, because the interpolated
    ``XYZtoCamera`` depends on the xy sought. From ``xy₀`` = D50:
    ``xyₖ₊₁ = xy(XYZtoCamera(xyₖ)⁻¹ · neutral)`` until
    ``|Δx| + |Δy| < 1e-7``, at most 30 passes, the last answer averaged with
    the one before when it oscillates (``dng_color_spec::NeutralToXY``).

    Examples
    --------
    >>> meta = CameraMeta(color_matrix_1=np.eye(3))
    >>> np.round(camera_neutral_to_xy(meta, xy_to_xyz([0.31, 0.32])), 6).tolist()
    [0.31, 0.32]
    """
    spec = _build_spec(meta, source)
    xy, _ = spec.neutral_to_xy(_as_neutral(neutral, "camera neutral"))
    return xy


def xy_to_camera_neutral(meta: CameraMeta, xy, source: SourceName = "auto") -> np.ndarray:
    """Camera neutral of a white-balance chromaticity.

    Parameters
    ----------
    meta : CameraMeta
    xy : (2,) array_like
        CIE 1931 chromaticity of the scene white (AsShotWhiteXY).
    source : str
        See :data:`SOURCES`.

    Returns
    -------
    (3,) ndarray
        Camera neutral (R, G, B) scaled so its largest entry is 1 (entries
        pinned to [0.001, 1], as the SDK's CameraWhite).

    Notes
    -----
    DNG 1.7.1.0 chapter 6, "Translating White Balance xy Coordinates to
    Camera Neutral Coordinates": ``n = XYZtoCamera(xy) · XYZ(xy)`` with
    ``XYZtoCamera = AB·CC·CM`` interpolated at the CCT of ``xy``.

    Examples
    --------
    >>> meta = CameraMeta(color_matrix_1=np.eye(3))
    >>> np.round(xy_to_camera_neutral(meta, (0.3457, 0.3585)), 4).tolist()
    [0.9643, 1.0, 0.8251]
    """
    spec = _build_spec(meta, source)
    return spec.camera_white(_as_xy(xy, "white xy"))


def _solve(meta: CameraMeta, neutral, xy, source: str):
    """CameraToXYZ_D50 and the notes explaining it."""
    m, notes, _, _ = _solve_white(meta, neutral, xy, source)
    return m, notes


def _solve_white(meta: CameraMeta, neutral, xy, source: str):
    """CameraToXYZ_D50, its notes, the white xy and the camera white
    (the SDK's ``CameraWhite``: the white's camera neutral, max 1)."""
    if neutral is not None and xy is not None:
        raise ValueError("give the scene white as a camera neutral or as xy, not both")
    spec = _build_spec(meta, source)
    notes = []
    if neutral is None and xy is None:
        if meta.as_shot_neutral is not None:
            neutral, origin = meta.as_shot_neutral, "AsShotNeutral"
        elif meta.as_shot_white_xy is not None:
            xy, origin = meta.as_shot_white_xy, "AsShotWhiteXY"
        else:
            xy, origin = DEFAULT_WHITE_XY, "no AsShotNeutral/AsShotWhiteXY: D55 (DNG SDK default)"
    else:
        origin = "camera neutral" if neutral is not None else "white xy"
    if neutral is not None:
        n = _as_neutral(neutral, "camera neutral")
        white, warn = spec.neutral_to_xy(n)
        notes.append(f"white from {origin} {_fmt(n)}")
        if warn:
            notes.append(warn)
    else:
        white = _as_xy(xy, "white xy")
        notes.append(f"white from {origin}")

    m, found, forward = spec.camera_to_pcs(white)
    path = "ForwardMatrix" if forward else "ColorMatrix⁻¹ + Bradford"
    head = f"{path}: xy {_fmt(white)}, {found.cct:.0f} K"
    if len(spec.calibrations) == 2:
        c1, c2 = spec.calibrations
        head += (f", weight {found.weight:.3f} on {c1.describe()}, "
                 f"{1 - found.weight:.3f} on {c2.describe()}")
    else:
        head += f"; {spec.label}"
    return m, (head, *notes, *spec.notes), white, spec.camera_white(white, found)


def camera_to_xyz_d50(meta: CameraMeta, neutral=None, xy=None,
                      source: SourceName = "auto") -> tuple[np.ndarray, tuple[str, ...]]:
    """DNG CameraToXYZ_D50: unbalanced camera RGB → CIE XYZ (D50).

    Parameters
    ----------
    meta : CameraMeta
        The colour tags of the file.
    neutral : (3,) array_like, optional
        Camera neutral of the scene white; default ``meta.as_shot_neutral``.
    xy : (2,) array_like, optional
        Scene white as a chromaticity instead of ``neutral``; default
        ``meta.as_shot_white_xy``. With neither tag the SDK's D55 is used.
    source : str
        Which matrices, by name: one of :data:`SOURCES`.

    Returns
    -------
    matrix : (3, 3) ndarray, float64
        ``XYZ_D50 = matrix · camera_rgb``; the camera neutral scaled to
        maximum 1 maps to the D50 white with Y = 1.
    notes : tuple of str
        First a one-line summary (path, white xy, CCT, weights), then where
        the white came from and any fallback taken.

    Raises
    ------
    ValueError
        Unknown ``source`` (the message lists the valid names), or a bad
        neutral / xy.
    InputError
        The file lacks the tags ``source`` asks for, or has no ColorMatrix.

    Notes
    -----
    DNG 1.7.1.0 chapter 6, "Camera to XYZ (D50) Transform", with the SDK's
    normalisations (module docstring). With ForwardMatrix:

    ``CameraToXYZ_D50 = FM · diag((AB·CC)⁻¹·n)⁻¹ · (AB·CC)⁻¹``

    without: ``CameraToXYZ_D50 = s · Bradford(white → D50) · (AB·CC·CM)⁻¹``
    with ``s = max(AB·CC·CM · XYZ(white))`` so that ``n / max(n)`` → Y = 1.

    Examples
    --------
    >>> meta = CameraMeta(color_matrix_1=np.eye(3), as_shot_white_xy=(0.3457, 0.3585))
    >>> m, notes = camera_to_xyz_d50(meta)
    >>> np.round(m @ xy_to_camera_neutral(meta, (0.3457, 0.3585)), 4).tolist()
    [0.9643, 1.0, 0.8251]
    >>> notes[0]
    'ColorMatrix⁻¹ + Bradford: xy (0.3457, 0.3585), 5001 K; ColorMatrix1 alone, no interpolation (the file has one ColorMatrix; CalibrationIlluminant1 missing)'
    """
    return _solve(meta, neutral, xy, source)


def camera_to_linear_srgb(meta: CameraMeta, applied_neutral=None, scene_neutral=None,
                          source: SourceName = "auto") -> tuple[np.ndarray, tuple[str, ...]]:
    """The 3×3 matrix from (white-balanced) camera RGB to linear sRGB (D65).

    Parameters
    ----------
    meta : CameraMeta
    applied_neutral : (3,) array_like, optional
        The neutral the data was balanced with (``balanced = raw / neutral``);
        None when the data is not balanced.
    scene_neutral : (3,) array_like, optional
        The scene white as a camera neutral; default ``meta.as_shot_neutral``
        (or ``meta.as_shot_white_xy``).
    source : str
        One of :data:`SOURCES`.

    Returns
    -------
    matrix : (3, 3) ndarray, float64
        ``sRGB = matrix · camera``.
    notes : tuple of str
        As :func:`camera_to_xyz_d50`; ``("no colour matrix: camera RGB
        treated as linear sRGB",)`` with the identity when the file has no
        ColorMatrix.

    Notes
    -----
    ``M = M_XYZ(D50)→sRGB · CameraToXYZ_D50 · diag(applied_neutral)``: the
    balance is undone, the DNG model applied, then Bradford D50 → D65 and the
    sRGB primaries (:func:`matrix_xyz_d50_to_linear_srgb`). When the applied
    neutral is the scene neutral scaled to maximum 1 (the usual G = 1),
    balanced (1, 1, 1) maps to sRGB (1, 1, 1).

    Examples
    --------
    >>> meta = CameraMeta(color_matrix_1=np.eye(3), as_shot_neutral=(0.5, 1.0, 0.7))
    >>> m, _ = camera_to_linear_srgb(meta, applied_neutral=(0.5, 1.0, 0.7))
    >>> np.round(m @ np.ones(3), 6).tolist()
    [1.0, 1.0, 1.0]
    >>> m, notes = camera_to_linear_srgb(CameraMeta())
    >>> m.tolist(), notes
    ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], ('no colour matrix: camera RGB treated as linear sRGB',))
    """
    check_source(source)
    if not _has_color_matrix(meta):
        return np.eye(3), ("no colour matrix: camera RGB treated as linear sRGB",)
    m, notes = camera_to_xyz_d50(meta, neutral=scene_neutral, source=source)
    m = matrix_xyz_d50_to_linear_srgb() @ m
    if applied_neutral is not None:
        m = m @ np.diag(_as_neutral(applied_neutral, "applied neutral"))
    return m, notes


# --------------------------------------------------------------------------
# Adobe's render spaces (the SDK's dng_color_space)

def rgb_to_pcs_matrix(m) -> np.ndarray:
    """An RGB → XYZ (D50) matrix with its rows rescaled so that RGB white
    maps to the PCS white exactly.

    Parameters
    ----------
    m : (3, 3) array_like
        A published, rounded RGB → XYZ D50 matrix (e.g.
        :data:`PROPHOTO_TO_XYZ_D50`).

    Returns
    -------
    (3, 3) ndarray, float64

    Notes
    -----
    ``dng_color_space::SetMatrixToPCS``: ``M' = diag(XYZ_D50 / (M·1)) · M``
    with ``XYZ_D50`` from xy (0.3457, 0.3585), Y = 1; rounding of the
    published four decimals would otherwise tint white.

    Examples
    --------
    >>> np.round(rgb_to_pcs_matrix(PROPHOTO_TO_XYZ_D50) @ np.ones(3), 4).tolist()
    [0.9643, 1.0, 0.8251]
    """
    m = _as_matrix(m, "RGB to PCS matrix")
    return (_pcs_xyz() / (m @ np.ones(3)))[:, None] * m


def matrix_xyz_d50_to_prophoto() -> np.ndarray:
    """XYZ (D50) → linear ProPhoto RGB, the inverse of
    ``rgb_to_pcs_matrix(PROPHOTO_TO_XYZ_D50)`` (``MatrixFromPCS``).

    Examples
    --------
    >>> np.round(matrix_xyz_d50_to_prophoto() @ xy_to_xyz(PCS_WHITE_XY), 6).tolist()
    [1.0, 1.0, 1.0]
    """
    return np.linalg.inv(rgb_to_pcs_matrix(PROPHOTO_TO_XYZ_D50))


def matrix_prophoto_to_srgb() -> np.ndarray:
    """Linear ProPhoto RGB → linear sRGB through the D50 PCS, as Adobe's
    renderer converts its working space to the output space.

    Returns
    -------
    (3, 3) ndarray
        ``sRGB = M · ProPhoto``; white maps to white.

    Notes
    -----
    ``fRGBtoFinal = sRGB.MatrixFromPCS · ProPhoto.MatrixToPCS`` in
    ``dng_render_task::Start``, both spaces from their D50 matrices
    (:data:`SRGB_TO_XYZ_D50`, :data:`PROPHOTO_TO_XYZ_D50`) rescaled by
    :func:`rgb_to_pcs_matrix`. The chromatic adaptation to the sRGB white
    is inside the published sRGB D50 matrix (Bradford), so this matrix
    differs from ``matrix_xyz_d50_to_linear_srgb() · ProPhoto`` by the
    rounding of those four-decimal colorants (< 5e-4 per element).

    Examples
    --------
    >>> np.round(matrix_prophoto_to_srgb() @ np.ones(3), 6).tolist()
    [1.0, 1.0, 1.0]
    """
    return np.linalg.inv(rgb_to_pcs_matrix(SRGB_TO_XYZ_D50)) @ rgb_to_pcs_matrix(PROPHOTO_TO_XYZ_D50)


def camera_to_prophoto(meta: CameraMeta, neutral=None, xy=None, source: SourceName = "auto"
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[str, ...]]:
    """Camera RGB → linear ProPhoto RGB, with the camera white and the scene
    white it was solved for: the colour inputs of Adobe's render.

    Parameters
    ----------
    meta : CameraMeta
    neutral, xy : array_like, optional
        The scene white as a camera neutral or a chromaticity; default as
        :func:`camera_to_xyz_d50` (AsShotNeutral, AsShotWhiteXY, else D55).
    source : str
        One of :data:`SOURCES`.

    Returns
    -------
    matrix : (3, 3) ndarray
        ``ProPhoto = matrix · camera`` for *unbalanced* camera RGB (white
        level 1); the camera white maps to ProPhoto (1, 1, 1).
    camera_white : (3,) ndarray
        The camera neutral of the scene white, largest entry 1, pinned to
        [0.001, 1]: where each camera channel clips (the SDK's
        ``CameraWhite``).
    white_xy : (2,) ndarray
        The scene white's chromaticity (its CCT selects the HueSatMap
        interpolation).
    notes : tuple of str
        As :func:`camera_to_xyz_d50`.

    Raises
    ------
    InputError
        The file has no ColorMatrix (or lacks what ``source`` asks for).

    Notes
    -----
    ``dng_render_task::Start``: ``fCameraToRGB = ProPhoto.MatrixFromPCS ·
    CameraToPCS`` with CameraToPCS from :func:`camera_to_xyz_d50` for the
    white from ``NeutralToXY(AsShotNeutral)`` (DNG 1.7.1.0 chapter 6).

    Examples
    --------
    >>> meta = CameraMeta(color_matrix_1=np.eye(3), as_shot_neutral=(0.5, 1.0, 0.7))
    >>> m, white, xy, _ = camera_to_prophoto(meta)
    >>> np.round(m @ white, 6).tolist(), np.round(white, 4).tolist()
    ([1.0, 1.0, 1.0], [0.5, 1.0, 0.7])
    """
    m, notes, white_xy, camera_white = _solve_white(meta, neutral, xy, source)
    return matrix_xyz_d50_to_prophoto() @ m, camera_white, white_xy, notes

