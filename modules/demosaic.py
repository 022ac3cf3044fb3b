"""Demosaicing: a Bayer mosaic ``(H, W)`` to camera RGB ``(H, W, 3)``.

Five methods, chosen by name through :data:`METHODS` (or :func:`demosaic`):

==============  ===============================================  =======  ======
name            function                                         CPSNR    16 MP
==============  ===============================================  =======  ======
``bilinear``    :func:`demosaic_bilinear`                        26.8 dB  0.12 s
``malvar2004``  :func:`demosaic_malvar2004`                      32.3 dB  0.20 s
``menon2007``   :func:`demosaic_menon2007` (colour-demosaicing)  39.6 dB  14 s
``opencv_ea``   :func:`demosaic_opencv`, ``variant="ea"``        27.0 dB  0.14 s
``opencv_vng``  :func:`demosaic_opencv`, ``variant="vng"``       29.8 dB  0.23 s
==============  ===============================================  =======  ======

CPSNR: kodim19 (500 × 500 centre crop, sRGB-encoded values, RGGB, 8-px
border excluded), see ``tests/modules/test_demosaic.py``. Time: best of 7 on one
3000 × 5328 float32 mosaic, 2 CPU cores (Menon also peaks at 3.2 GB of
memory). Indications, not promises.

Data convention
---------------
mosaic : (H, W) ndarray, float
    Linear, black = 0, white ≈ 1. Values below 0 and above 1 are legitimate
    and kept. H, W ≥ 2 (≥ 3 for the OpenCV methods); odd sizes allowed;
    float64 is accepted and computed in float32.
cfa : :class:`~isp.frame.CFA` or its name
    The pattern at ``mosaic[0, 0]``; all four Bayer phases.
returns : (H, W, 3) ndarray, float32
    Camera RGB (0 R, 1 G, 2 B) on the mosaic's scale, never clipped (the
    OpenCV methods excepted, within the limits stated there).

``bilinear`` and ``malvar2004`` are linear filters run with
:func:`cv2.filter2D` in float32, with the border extended by mirroring about
the edge pixel (OpenCV ``BORDER_REFLECT_101``, scipy ``mode="mirror"``). That
mirror keeps the parity of every index, so the extended mosaic is itself a
valid Bayer mosaic of the same phase: a constant colour is reproduced exactly
up to the last row and column, and sampled values are returned unchanged at
their own sites everywhere. (colour-demosaicing's bilinear and Malvar use
scipy's default ``mode="reflect"``, mirroring about the pixel *edge*; that
swaps the CFA phase outside the frame, so the two agree only from one pixel
(bilinear) or two (Malvar) inside the border; on the edge itself theirs can
be off by most of the signal.)

OpenCV's Bayer naming
---------------------
OpenCV names a Bayer pattern by the *second* row's second and third pixels,
not by the top-left 2×2 block used here: an ``RGGB`` sensor is
``COLOR_BayerBG2RGB``. Recent OpenCV releases add four-letter aliases
(``COLOR_BayerRGGB2RGB == COLOR_BayerBG2RGB``); the two-letter names exist in
every release, so they are used here, through :data:`OPENCV_BAYER`, which the
tests verify on synthetic mosaics of all four phases. Note also that
``COLOR_BayerRG2RGB`` and ``COLOR_BayerBG2BGR`` are the *same* code.

References
----------
.. [1] Gunturk, B. K., Glotzbach, J., Altunbasak, Y., Schafer, R. W., &
   Mersereau, R. M. (2005). Demosaicking: color filter array interpolation.
   *IEEE Signal Processing Magazine*, 22(1), 44–54.
   doi:10.1109/MSP.2005.1407714
.. [2] Malvar, H. S., He, L.-W., & Cutler, R. (2004). High-quality linear
   interpolation for demosaicing of Bayer-patterned color images. *Proc. IEEE
   International Conference on Acoustics, Speech, and Signal Processing
   (ICASSP 2004)*, vol. 3, pp. iii-485–488. doi:10.1109/ICASSP.2004.1326587
.. [3] Menon, D., Andriani, S., & Calvagno, G. (2007). Demosaicing with
   directional filtering and a posteriori decision. *IEEE Transactions on
   Image Processing*, 16(1), 132–141. doi:10.1109/TIP.2006.884928
.. [4] Chang, E., Cheung, S., & Pan, D. Y. (1999). Color filter array
   recovery using a threshold-based variable number of gradients. *Proc. SPIE
   3650, Sensors, Cameras, and Applications for Digital Photography*, 36–43.
.. [5] OpenCV, ``cv::demosaicing`` / ``cv::cvtColor`` with
   ``COLOR_Bayer**2RGB_EA`` (edge-aware) and ``_VNG``;
   ``modules/imgproc/src/demosaicing.cpp``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, ClassVar, Literal, get_args

import cv2
import numpy as np

from isp.errors import InputError
from isp.frame import CFA, Domain, Frame
from isp.stage import StageBase

__all__ = [
    "METHODS", "OPENCV_BAYER", "Demosaic", "demosaic", "demosaic_bilinear",
    "demosaic_malvar2004", "demosaic_menon2007", "demosaic_opencv",
]

Method = Literal["bilinear", "malvar2004", "menon2007", "opencv_ea", "opencv_vng"]

#: ``method`` value that lets the lens profile choose (:meth:`Demosaic.method_for`)
AUTO = "auto"
#: what the stage's ``method`` accepts: a method, or :data:`AUTO`
StageMethod = Literal["bilinear", "malvar2004", "menon2007", "opencv_ea", "opencv_vng", "auto"]

#: mirror about the edge pixel: keeps the CFA phase outside the frame
_BORDER = cv2.BORDER_REFLECT_101


# --------------------------------------------------------------------------
# helpers

def _as_mosaic(mosaic) -> np.ndarray:
    """``mosaic`` as a C-contiguous float32 (H, W) array (no copy if it is
    one already); ValueError naming what came otherwise."""
    m = np.asarray(mosaic)
    if m.ndim != 2:
        raise ValueError(f"mosaic must be a 2-D (H, W) array, got shape {m.shape}")
    if min(m.shape) < 2:
        raise ValueError(f"mosaic must be at least 2 x 2 (one Bayer block), got shape {m.shape}")
    if not np.issubdtype(m.dtype, np.floating):
        raise ValueError(
            f"mosaic must be float (linear, white = 1), got dtype {m.dtype}; "
            "subtract the black level and divide by the white level first")
    return np.ascontiguousarray(m, dtype=np.float32)


def _sites(cfa: CFA) -> tuple[tuple[int, int], ...]:
    """(row, col) offsets in the 2×2 block of R, B, G-in-R-rows, G-in-B-rows."""
    (rr, rc), = cfa.positions(0)
    (br, bc), = cfa.positions(2)
    return (rr, rc), (br, bc), (rr, 1 - rc), (br, 1 - bc)


def _sparse(m: np.ndarray, *sites: tuple[int, int]) -> np.ndarray:
    """``m`` at the given CFA sites, zero elsewhere (strided copies only)."""
    out = np.zeros_like(m)
    for r, c in sites:
        out[r::2, c::2] = m[r::2, c::2]
    return out


def _filter(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Correlation of ``x`` with ``kernel`` (all kernels here are symmetric
    under a half turn, so it equals convolution), reflect-101 border."""
    return cv2.filter2D(x, cv2.CV_32F, kernel, borderType=_BORDER)


def _by_bands(m: np.ndarray, radius: int, planes) -> np.ndarray:
    """``cv2.merge(planes(m))``, computed a band of rows at a time.

    ``planes(strip)`` returns the three (rows, W) float32 planes of a
    filter of at most ``radius`` rows either side. Each band is filtered
    with ``radius`` rows of its neighbours above and below (an even count,
    so the strip starts on the mosaic's own CFA phase) and only its own rows
    are kept; at the mosaic's top and bottom the strip ends where the
    mosaic does, so the border extension is the mosaic's own. Every output
    value is the one the whole-mosaic filter gives, while the temporary
    planes stay small (cache-resident) and the only full-size array is the
    (H, W, 3) result.
    """
    h, w = m.shape
    halo = radius + radius % 2
    band = max(2, (_BAND_VALUES // max(w, 1)) & ~1)
    out = np.empty((h, w, 3), np.float32)
    for b0 in range(0, h, band):
        b1 = min(b0 + band, h)
        s0, s1 = max(b0 - halo, 0), min(b1 + halo, h)
        cv2.merge([p[b0 - s0:b1 - s0] for p in planes(m[s0:s1])], dst=out[b0:b1])
    return out


#: mosaic values per band of :func:`_by_bands` (512 KiB of float32 per
#: plane: a band's temporaries stay in cache)
_BAND_VALUES = 1 << 17


# --------------------------------------------------------------------------
# bilinear

_K_G = np.array([[0, 1, 0],
                 [1, 4, 1],
                 [0, 1, 0]], np.float32) / 4
_K_RB = np.array([[1, 2, 1],
                  [2, 4, 2],
                  [1, 2, 1]], np.float32) / 4


def demosaic_bilinear(mosaic, cfa: CFA | str) -> np.ndarray:
    """Bilinear demosaicing: each missing sample is the mean of its nearest
    neighbours of that colour (2 or 4 of them).

    Parameters
    ----------
    mosaic : (H, W) ndarray, float
        Linear Bayer mosaic, white ≈ 1; not clipped. H, W ≥ 2.
    cfa : CFA or str
        Pattern at ``mosaic[0, 0]``.

    Returns
    -------
    (H, W, 3) ndarray, float32
        Camera RGB on the mosaic's scale.

    Notes
    -----
    Each colour plane is the mosaic masked to its sites, convolved with
    ``K_G = [[0,1,0],[1,4,1],[0,1,0]]/4`` (green, quincunx) or
    ``K_RB = [[1,2,1],[2,4,2],[1,2,1]]/4`` (red, blue) [1]_. Sampled values
    are returned unchanged; functions linear in x or y are reproduced exactly
    away from the border; the border is mirrored about the edge pixel (see
    the module notes), so a constant colour is exact everywhere.

    Examples
    --------
    >>> m = np.array([[0.25, 0.5], [0.5, 0.75]], np.float32)  # one RGGB block
    >>> demosaic_bilinear(np.tile(m, (2, 2)), CFA.RGGB)[1, 1].tolist()
    [0.25, 0.5, 0.75]
    """
    m = _as_mosaic(mosaic)
    red, blue, g_r, g_b = _sites(CFA.parse(cfa))
    return _by_bands(m, 1, lambda s: [
        _filter(_sparse(s, red), _K_RB),
        _filter(_sparse(s, g_r, g_b), _K_G),
        _filter(_sparse(s, blue), _K_RB),
    ])


# --------------------------------------------------------------------------
# Malvar, He & Cutler (2004)

#: G at R and B sites (Malvar et al. 2004, fig. 2, top row; α = 1/2)
_K_MALVAR_G = np.array([[0, 0, -1, 0, 0],
                        [0, 0, 2, 0, 0],
                        [-1, 2, 4, 2, -1],
                        [0, 0, 2, 0, 0],
                        [0, 0, -1, 0, 0]], np.float32) / 8
#: R (B) at a G site whose row holds R (B): same-colour neighbours left and
#: right (fig. 2, "R at green in R row, B column"; β = 5/8)
_K_MALVAR_ROW = np.array([[0, 0, 0.5, 0, 0],
                          [0, -1, 0, -1, 0],
                          [-1, 4, 5, 4, -1],
                          [0, -1, 0, -1, 0],
                          [0, 0, 0.5, 0, 0]], np.float32) / 8
#: R (B) at a G site whose column holds R (B): the transpose
_K_MALVAR_COL = np.ascontiguousarray(_K_MALVAR_ROW.T)
#: R at B sites and B at R sites (fig. 2, "R at blue in B row, B column";
#: γ = 3/4)
_K_MALVAR_DIAG = np.array([[0, 0, -1.5, 0, 0],
                           [0, 2, 0, 2, 0],
                           [-1.5, 0, 6, 0, -1.5],
                           [0, 2, 0, 2, 0],
                           [0, 0, -1.5, 0, 0]], np.float32) / 8


def _put(dst: np.ndarray, src: np.ndarray, site: tuple[int, int]) -> None:
    """``dst`` takes ``src``'s values at one CFA site (a strided copy)."""
    r, c = site
    dst[r::2, c::2] = src[r::2, c::2]


def demosaic_malvar2004(mosaic, cfa: CFA | str) -> np.ndarray:
    """Malvar–He–Cutler gradient-corrected linear demosaicing [2]_.

    Parameters
    ----------
    mosaic : (H, W) ndarray, float
        Linear Bayer mosaic, white ≈ 1; not clipped. H, W ≥ 2.
    cfa : CFA or str
        Pattern at ``mosaic[0, 0]``.

    Returns
    -------
    (H, W, 3) ndarray, float32
        Camera RGB on the mosaic's scale. The gradient correction can
        overshoot at edges (values below 0 or above the input's maximum);
        nothing is clipped.

    Notes
    -----
    Bilinear interpolation plus a Laplacian correction from the colour
    sampled at the site, e.g. for G at an R site (eq. 2 of [2]_)

    ``Ĝ(i,j) = Ĝ_bl(i,j) + α ΔR(i,j)``,  ``ΔR = R(i,j) − ¼ Σ R(i±2, j±2)``

    with gains α = 1/2, β = 5/8, γ = 3/4 folded into the four 5×5 filters of
    fig. 2 of [2]_ (each sums to 1, so a constant colour is exact). Each
    filter runs over the mosaic with :func:`cv2.filter2D` (a band of rows
    at a time) and the planes take its result at the sites where it
    applies.

    Examples
    --------
    >>> m = np.array([[0.25, 0.5], [0.5, 0.75]], np.float32)  # one RGGB block
    >>> demosaic_malvar2004(np.tile(m, (3, 3)), CFA.RGGB)[2, 3].tolist()
    [0.25, 0.5, 0.75]
    """
    m = _as_mosaic(mosaic)
    return _by_bands(m, 2, lambda s: _malvar_planes(s, *_sites(CFA.parse(cfa))))


def _malvar_planes(m: np.ndarray, red, blue, g_r, g_b) -> list[np.ndarray]:
    """The R, G, B planes of :func:`demosaic_malvar2004` for mosaic ``m``."""
    green = _filter(m, _K_MALVAR_G)
    _put(green, m, g_r)
    _put(green, m, g_b)

    # The row-kernel result is R at G-in-R-rows and B at G-in-B-rows; the
    # column-kernel result the other way round. Each becomes one plane after
    # the two exchange their values at G-in-B-rows.
    red_plane = _filter(m, _K_MALVAR_ROW)
    blue_plane = _filter(m, _K_MALVAR_COL)
    r, c = g_b
    swap = red_plane[r::2, c::2].copy()
    red_plane[r::2, c::2] = blue_plane[r::2, c::2]
    blue_plane[r::2, c::2] = swap

    diag = _filter(m, _K_MALVAR_DIAG)
    _put(red_plane, diag, blue)
    _put(blue_plane, diag, red)
    _put(red_plane, m, red)
    _put(blue_plane, m, blue)
    return [red_plane, green, blue_plane]


# --------------------------------------------------------------------------
# Menon, Andriani & Calvagno (2007)

def demosaic_menon2007(mosaic, cfa: CFA | str, refining_step: bool = True) -> np.ndarray:
    """DDFAPD: directional filtering with a posteriori decision [3]_, by
    colour-demosaicing's ``demosaicing_CFA_Bayer_Menon2007``.

    Parameters
    ----------
    mosaic : (H, W) ndarray, float
        Linear Bayer mosaic, white ≈ 1; not clipped. H, W ≥ 2.
    cfa : CFA or str
        Pattern at ``mosaic[0, 0]``.
    refining_step : bool
        Run the paper's refining step (section III-C).

    Returns
    -------
    (H, W, 3) ndarray, float32
        Camera RGB on the mosaic's scale, not clipped.

    Notes
    -----
    Green is interpolated horizontally and vertically (5-tap filters
    ``[0, ½, 0, ½, 0] + [−¼, 0, ½, 0, −¼]``), the direction with the smaller
    sum of colour-difference gradients over a 5×5 neighbourhood is kept, and
    red/blue follow from colour differences in that direction. Computed in
    float64 by the library (about 14 s and 3 GB at 16 MP: a reference,
    not a production path); its border extension is a mirror for the
    filters but zeros for the direction decision.

    Examples
    --------
    >>> m = np.array([[0.25, 0.5], [0.5, 0.75]], np.float32)  # one RGGB block
    >>> demosaic_menon2007(np.tile(m, (3, 3)), CFA.RGGB)[2, 3].tolist()
    [0.25, 0.5, 0.75]
    """
    # imported here: colour-science takes seconds to import
    from colour_demosaicing import demosaicing_CFA_Bayer_Menon2007

    m = _as_mosaic(mosaic)
    rgb = demosaicing_CFA_Bayer_Menon2007(
        m.astype(np.float64), CFA.parse(cfa).value, refining_step=refining_step)
    return rgb.astype(np.float32)


# --------------------------------------------------------------------------
# OpenCV edge-aware and VNG

#: OpenCV's two-letter pattern name for each CFA (its second row, second and
#: third pixels; see the module notes)
OPENCV_BAYER = {CFA.RGGB: "BG", CFA.BGGR: "RG", CFA.GRBG: "GB", CFA.GBRG: "GR"}

#: per variant: OpenCV code suffix and the integer type it demands
_OPENCV_VARIANTS = {"ea": ("_EA", np.uint16), "vng": ("_VNG", np.uint8)}

#: fraction of the integer range left free below and above the data, so that
#: interpolation overshoot is not cut off by integer saturation
_HEADROOM = 1 / 8


def _quantisation(lo: float, hi: float, dtype) -> tuple[float, float]:
    """(scale, offset) mapping [lo, hi] onto the integer codes
    [h·Q, (1 − h)·Q], Q = the type's maximum, h = :data:`_HEADROOM`."""
    q = float(np.iinfo(dtype).max)
    scale = q * (1 - 2 * _HEADROOM) / (hi - lo)
    return scale, q * _HEADROOM - lo * scale


def demosaic_opencv(mosaic, cfa: CFA | str, variant: Literal["ea", "vng"] = "ea") -> np.ndarray:
    """OpenCV's edge-aware (``"ea"``) or variable-number-of-gradients
    (``"vng"``, [4]_) demosaicing [5]_, through integer quantisation.

    Parameters
    ----------
    mosaic : (H, W) ndarray, float
        Linear Bayer mosaic, white ≈ 1, finite. H, W ≥ 3.
    cfa : CFA or str
        Pattern at ``mosaic[0, 0]``.
    variant : {"ea", "vng"}
        ``"ea"`` runs on 16-bit codes, ``"vng"`` on 8-bit codes (OpenCV
        implements VNG for 8-bit input only).

    Returns
    -------
    (H, W, 3) ndarray, float32
        Camera RGB on the mosaic's scale, carrying the quantisation error
        described in Notes.

    Raises
    ------
    ValueError
        Unknown ``variant``, a mosaic with NaN or infinity (no finite
        range to quantise), or one smaller than 3 × 3 (where OpenCV returns
        zeros without a word).

    Notes
    -----
    OpenCV demosaics integers only. The range ``[lo, hi]`` with
    ``lo = min(0, min x)`` and ``hi = max(1, max x)`` is mapped affinely onto
    the codes ``[Q/8, 7Q/8]`` (Q = 65535 for EA, 255 for VNG), rounded,
    demosaiced and mapped back. Hence:

    * values above 1 and below 0 keep their place: nothing is clipped on the
      way in (both OpenCV methods commute exactly with an integer offset,
      which the tests check, so the shift is harmless);
    * every value is known to about one step ``Δ = (hi − lo) / (0.75 Q)``:
      ``Δ ≈ 2.0e-5`` (EA) and ``5.2e-3`` (VNG, about 7.6 bits over 0..1)
      for data in [0, 1]; input rounding contributes ``Δ/2``, OpenCV's
      integer arithmetic up to about one more step;
    * interpolated values overshooting the data's range by more than
      ``(hi − lo)/6`` saturate at the integer limits: the one clipping
      left, a limit of the integer path. EA was not seen to overshoot at
      all; VNG does at edges and hit the limit at 5 of 750 000 values on
      kodim19;
    * EA fills its outermost row and column by copying their inner
      neighbours (an OpenCV border rule), so sampled values are not exact
      there.

    Examples
    --------
    >>> m = np.array([[0.25, 0.5], [0.5, 0.75]], np.float32)  # one RGGB block
    >>> rgb = demosaic_opencv(np.tile(m, (3, 3)), CFA.RGGB)
    >>> bool(np.allclose(rgb[2, 3], [0.25, 0.5, 0.75], atol=1e-4))
    True
    """
    try:
        suffix, dtype = _OPENCV_VARIANTS[variant]
    except KeyError:
        raise ValueError(
            f"unknown OpenCV demosaic variant {variant!r}; valid: "
            f"{', '.join(_OPENCV_VARIANTS)}") from None
    m = _as_mosaic(mosaic)
    if min(m.shape) < 3:  # OpenCV returns zeros, silently, below 3 x 3
        raise ValueError(f"OpenCV demosaicing needs a mosaic of at least 3 x 3, got shape {m.shape}")
    lo, hi = float(m.min()), float(m.max())
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"mosaic must be finite for OpenCV demosaicing, got range [{lo}, {hi}]")
    scale, offset = _quantisation(min(0.0, lo), max(1.0, hi), dtype)
    codes = np.rint(m * np.float32(scale) + np.float32(offset)).astype(dtype)
    code = getattr(cv2, f"COLOR_Bayer{OPENCV_BAYER[CFA.parse(cfa)]}2RGB{suffix}")
    rgb = cv2.cvtColor(codes, code).astype(np.float32)
    rgb -= np.float32(offset)
    rgb *= np.float32(1 / scale)
    return rgb


# --------------------------------------------------------------------------
# choice by name

#: demosaicing functions by method name: ``f(mosaic, cfa) -> (H, W, 3)``
METHODS: dict[str, Callable[..., np.ndarray]] = {
    "bilinear": demosaic_bilinear,
    "malvar2004": demosaic_malvar2004,
    "menon2007": demosaic_menon2007,
    "opencv_ea": functools.partial(demosaic_opencv, variant="ea"),
    "opencv_vng": functools.partial(demosaic_opencv, variant="vng"),
}
assert tuple(METHODS) == get_args(Method)  # one list of names, checked at import


def _check_method(method: str) -> None:
    if method not in METHODS:
        raise ValueError(f"unknown demosaic method {method!r}; valid: {', '.join(METHODS)}")


def demosaic(mosaic, cfa: CFA | str, method: str = "bilinear") -> np.ndarray:
    """Demosaic ``mosaic`` with the method named ``method`` (a key of
    :data:`METHODS`).

    Parameters
    ----------
    mosaic : (H, W) ndarray, float
        Linear Bayer mosaic, white ≈ 1; not clipped. H, W ≥ 2.
    cfa : CFA or str
        Pattern at ``mosaic[0, 0]``.
    method : str
        ``"bilinear"``, ``"malvar2004"``, ``"menon2007"``, ``"opencv_ea"``
        or ``"opencv_vng"``.

    Returns
    -------
    (H, W, 3) ndarray, float32

    Examples
    --------
    >>> demosaic(np.ones((4, 4), np.float32), "GRBG", method="malvar2004").shape
    (4, 4, 3)
    >>> demosaic(np.ones((4, 4), np.float32), "GRBG", method="ahd")
    Traceback (most recent call last):
    ...
    ValueError: unknown demosaic method 'ahd'; valid: bilinear, malvar2004, menon2007, opencv_ea, opencv_vng
    """
    _check_method(method)
    return METHODS[method](mosaic, cfa)


# --------------------------------------------------------------------------
# the stage

@dataclass(frozen=True)
class Demosaic(StageBase):
    """Stage: a linear mosaic (``raw_linear``) to camera RGB.

    Parameters
    ----------
    method : str
        A key of :data:`METHODS`, or ``"auto"``: the method the profile of
        the frame's lens names (:class:`isp.profiles.Profile`'s
        ``demosaic``: what its correction model was trained after), else
        bilinear, as the Adobe DNG SDK's render demosaics (``dng_mosaic_info``).

    Notes
    -----
    The pattern comes from ``frame.meta.cfa``, taken as the pattern at
    ``frame.data[0, 0]``. A frame whose data already has three channels (a
    linear DNG, demosaiced in camera) passes through unchanged, only its
    domain advancing to ``camera_rgb``.

    Examples
    --------
    >>> from isp import CameraMeta, Frame
    >>> frame = Frame(np.full((4, 6), 0.25, np.float32), Domain.RAW_LINEAR,
    ...               CameraMeta(cfa=CFA.RGGB))
    >>> out = Demosaic(method="malvar2004")(frame)
    >>> out.domain.value, out.shape, str(out.history[-1])
    ('camera_rgb', (4, 6, 3), 'demosaic: malvar2004')
    """

    name: ClassVar[str] = "demosaic"
    consumes: ClassVar[tuple[Domain, ...]] = (Domain.RAW_LINEAR,)
    produces: ClassVar[Domain] = Domain.CAMERA_RGB

    method: StageMethod = "malvar2004"

    def __post_init__(self):
        if self.method != AUTO:
            _check_method(self.method)

    def method_for(self, meta) -> tuple[str, str]:
        """The method this stage uses on a capture with ``meta``, and why."""
        if self.method != AUTO:
            return self.method, self.method
        from isp.profiles import match_profile

        profile = match_profile(meta).profile
        if profile is not None and profile.demosaic:
            _check_method(profile.demosaic)
            return profile.demosaic, f"{profile.demosaic} (auto: lens profile {profile.name!r})"
        return "bilinear", "bilinear (auto: as Adobe's SDK; no lens profile names a method)"

    def process(self, frame: Frame) -> Frame:
        data = frame.data
        if data.ndim == 3 and data.shape[-1] == 3:
            return frame.evolve(domain=Domain.CAMERA_RGB, stage=self.name,
                                note="passed through: data already demosaiced (LinearRaw)")
        if data.ndim != 2:
            raise InputError(frame.meta.path,
                             f"demosaic expects an (H, W) mosaic or (H, W, 3) data, got shape {data.shape}")
        if frame.meta.cfa is None:
            raise InputError(frame.meta.path, "mosaic without a CFA pattern")
        method, note = self.method_for(frame.meta)
        try:
            rgb = demosaic(data, frame.meta.cfa, method)
        except ValueError as e:  # data the method cannot take (too small, non-finite)
            raise InputError(frame.meta.path, f"demosaic {method}: {e}") from None
        return frame.evolve(rgb, domain=Domain.CAMERA_RGB, stage=self.name, note=note)
