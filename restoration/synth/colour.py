"""Display sRGB back to the camera RGB the correction slot sees: the inverse
of the pipeline's stages after the slot, with real phone colour metadata
(paper, section 4.1: "raw-like image", luminosity compression/decompression).

The correction is trained and evaluated on the ``linear`` look, whose
stages after the correction slot are ``luminance → ccm → gamma``
(:data:`isp.pipeline.LOOKS`; the default ``adobe`` look renders with
``dng_render`` instead), so a display image ``L`` (sRGB) and
the slot's input ``J`` (white-balanced camera RGB, :class:`~isp.frame.Domain`
``camera_rgb``) are related by

.. math::

    L = \\mathrm{OETF}\\big(M\\,\\mathcal{T}_g(J)\\big),\\qquad
    J = \\mathcal{T}_g^{-1}\\big(M^{-1}\\,\\mathrm{EOTF}(L)\\big)

with ``OETF`` the sRGB encoding (IEC 61966-2-1:1999, 5.2;
:func:`modules.gamma.srgb_oetf`, inverse :func:`modules.gamma.srgb_eotf`),
``M`` the ccm stage's matrix (balanced camera RGB → linear sRGB,
:func:`modules.common.dng_colour.camera_to_linear_srgb` with the scene neutral as
the applied one, exactly as :class:`modules.ccm.ColorCorrection` builds it)
and ``𝒯_g`` the luminance stage (:func:`modules.luminance.adjust_luminance`:
gain ``g = 2^EV`` and an optional global tone curve; inverse
:func:`modules.luminance.invert_luminance`). The raw camera signal, before
the white-balance stage, is ``J · n`` with ``n`` the camera neutral (G = 1).

What is drawn per pair
----------------------
* the camera whose colour tags (ColorMatrix/ForwardMatrix, calibration
  illuminants) give ``M`` — one of the phone DNGs given;
* the scene white: one of ``steps`` CCTs equally spaced in mired within
  ``cct_k`` on the Planckian locus (Kang et al. 2002, via colour-science),
  turned into the camera neutral by the DNG model (DNG 1.7.1.0 chapter 6,
  :func:`modules.common.dng_colour.xy_to_camera_neutral`); the neutral and the
  matrix of every (camera, white) are computed once (:func:`colour_table`);
* the *luminosity compression*: an exposure ``EV`` uniform in ``exposure_ev``;
  the raw-like image is ``2^−EV`` times darker (so it is noisier, as an
  under-exposed capture), and the luminance stage's gain ``2^EV`` — the
  *decompression* — brings it back in ``Process``. ``EV`` is the stage's
  total exposure: ``BaselineExposure + Luminance.exposure``.

Domains
-------
===================  =========================================  ==========
array                meaning                                    range
===================  =========================================  ==========
``srgb``             display sRGB, (H, W, 3) float              [0, 1]
``camera``           balanced camera RGB, (H, W, 3) float32     ≈ [0, 1/g]
``neutral``          camera neutral (R, G, B), G = 1            (0, ∞)
``ccm``              (3, 3) balanced camera → linear sRGB
===================  =========================================  ==========

References
----------
* Brooks, T., Mildenhall, B., Xue, T., Chen, J., Sharlet, D., Barron, J. T.
  (2019). Unprocessing images for learned raw denoising. *CVPR 2019*,
  11036–11045 (the inverse-ISP recipe, here with the pipeline's own stages).
* Kang, B., Moon, O., Hong, C., Lee, H., Cho, B., Kim, Y. (2002). Design of
  advanced color temperature control system for HDTV applications.
  *J. Korean Phys. Soc.* 41(6), 865–871 (CCT → xy).
* Adobe, *DNG Specification* 1.7.1.0 (2023), chapter 6.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.meta import CameraMeta
from modules.ccm import apply_ccm
from modules.gamma import srgb_eotf, srgb_oetf
from modules.luminance import (
    BT709_Y,
    adjust_luminance,
    invert_luminance,
    luminance_weights,
)

__all__ = [
    "CameraProfile",
    "ColourTable",
    "PairColour",
    "camera_colour",
    "cct_to_xy",
    "colour_table",
    "draw_colour",
    "process_after_slot",
    "read_camera",
    "srgb_to_camera",
]


@dataclass(frozen=True, eq=False)
class CameraProfile:
    """The metadata of one real capture, used for its colour model and (the
    first one given) its sensor: CFA, levels, NoiseProfile.

    Attributes
    ----------
    path : str
    meta : CameraMeta
    """

    path: str
    meta: CameraMeta

    @property
    def name(self) -> str:
        m = self.meta
        return " ".join(v for v in (m.make, m.model) if v) or m.unique_camera_model or Path(self.path).name


def read_camera(path) -> CameraProfile:
    """A DNG's metadata, read by the project's reader (:func:`isp.io.read.read_raw`).

    Raises
    ------
    InputError
        Unreadable file, or one without a ColorMatrix (no colour model to
        invert).
    """
    from isp.io.read import read_raw

    p = Path(path)
    if not p.is_file():
        raise InputError(p, "no such camera metadata file (a DNG)")
    meta = read_raw(p).meta
    if meta.color_matrix_1 is None and meta.color_matrix_2 is None:
        raise InputError(p, "no ColorMatrix: its colour model cannot be inverted; give a DNG with colour tags")
    return CameraProfile(str(p), meta)


def cct_to_xy(cct: float) -> np.ndarray:
    """CIE 1931 xy of the Planckian radiator at ``cct`` kelvin
    (1667–25000 K; Kang et al. 2002, via colour-science).

    >>> np.round(cct_to_xy(6504.0), 3).tolist()
    [0.313, 0.324]
    """
    from colour.temperature import CCT_to_xy_Kang2002

    return np.asarray(CCT_to_xy_Kang2002(float(cct)), dtype=np.float64)


def camera_colour(meta: CameraMeta, xy) -> tuple[np.ndarray, np.ndarray]:
    """Camera neutral and ccm-stage matrix for a scene white.

    Parameters
    ----------
    meta : CameraMeta
        Colour tags of the camera.
    xy : (2,) array_like
        Scene white chromaticity.

    Returns
    -------
    neutral : (3,) ndarray
        Camera neutral with G = 1 (what the white-balance stage divides by).
    ccm : (3, 3) ndarray
        Balanced camera RGB → linear sRGB, as :class:`modules.ccm.ColorCorrection`
        computes it for a frame balanced with ``neutral``.
    """
    from modules.common.dng_colour import camera_to_linear_srgb, xy_to_camera_neutral

    n = np.asarray(xy_to_camera_neutral(meta, xy), dtype=np.float64)
    n = n / n[1]
    m, _ = camera_to_linear_srgb(meta, applied_neutral=n, scene_neutral=n)
    return n, m


@dataclass(frozen=True)
class PairColour:
    """The colour and exposure of one pair (what ``Process`` needs).

    Attributes
    ----------
    camera : int
        Index of the camera profile.
    cct : float
        Scene white, kelvin.
    neutral : (3,) ndarray
        Camera neutral, G = 1; the white-balance gains are ``1 / neutral``.
    ccm : (3, 3) ndarray
        Balanced camera RGB → linear sRGB.
    exposure_ev : float
        Total exposure of the luminance stage (gain ``2^EV``).
    luma_weights : (3,) ndarray
        Luminance weights of balanced camera RGB (used by a tone curve).
    """

    camera: int
    cct: float
    neutral: np.ndarray
    ccm: np.ndarray
    exposure_ev: float
    luma_weights: np.ndarray

    @property
    def gain(self) -> float:
        return float(2.0 ** self.exposure_ev)


@dataclass(frozen=True, eq=False)
class ColourTable:
    """Neutral, ccm and luminance weights of every camera at every scene
    white a plan draws from (computed once: the DNG colour model costs
    ~0.1 s a call).

    Attributes
    ----------
    cct : (S,) ndarray
        Scene whites, kelvin, equally spaced in mired.
    neutral : (C, S, 3) ndarray
    ccm : (C, S, 3, 3) ndarray
    luma_weights : (C, S, 3) ndarray
    """

    cct: np.ndarray
    neutral: np.ndarray
    ccm: np.ndarray
    luma_weights: np.ndarray


def colour_table(cameras: list[CameraProfile], cct_k=(2850.0, 7500.0), steps: int = 32) -> ColourTable:
    """The :class:`ColourTable` of ``cameras`` on ``steps`` whites equally
    spaced in mired over ``cct_k`` (kelvin). 32 steps over 2850–7500 K are
    6.8 mired apart, about the just-noticeable difference of a white."""
    lo, hi = float(cct_k[0]), float(cct_k[1])
    steps = 1 if lo == hi else max(2, int(steps))
    cct = 1e6 / np.linspace(1e6 / hi, 1e6 / lo, steps)
    nc = len(cameras)
    neutral, ccm, luma = np.zeros((nc, steps, 3)), np.zeros((nc, steps, 3, 3)), np.zeros((nc, steps, 3))
    for ci, cam in enumerate(cameras):
        for k, t in enumerate(cct):
            n, m = camera_colour(cam.meta, cct_to_xy(t))
            frame = Frame(np.zeros((1, 1, 3), np.float32), Domain.CAMERA_RGB, cam.meta,
                          neutral=tuple(float(v) for v in n))
            neutral[ci, k], ccm[ci, k] = n, m
            luma[ci, k] = np.asarray(luminance_weights(frame), dtype=np.float64)
    return ColourTable(cct, neutral, ccm, luma)


def draw_colour(table: ColourTable, rng: np.random.Generator, *, exposure_ev=(0.0, 2.0)) -> PairColour:
    """Draw a camera, a scene white (uniformly among the table's) and an
    exposure (uniform in ``exposure_ev``, EV) — see the module notes."""
    ci = int(rng.integers(table.neutral.shape[0]))
    k = int(rng.integers(table.cct.size))
    ev = float(rng.uniform(float(exposure_ev[0]), float(exposure_ev[1])))
    return PairColour(ci, float(table.cct[k]), table.neutral[ci, k], table.ccm[ci, k], ev, table.luma_weights[ci, k])


def srgb_to_camera(srgb, colour: PairColour, *, tone: str = "none", white: float = 4.0) -> np.ndarray:
    """Balanced camera RGB that the pipeline's stages after the slot turn
    into ``srgb`` (see the module equation).

    Parameters
    ----------
    srgb : (H, W, 3) ndarray, float in [0, 1]
        Display sRGB.
    colour : PairColour
    tone, white
        The luminance stage's tone curve and white point.

    Returns
    -------
    (H, W, 3) ndarray, float32; not clipped (a saturated sRGB colour may
    need a slightly negative camera value under a 3×3 model).

    >>> c = PairColour(0, 6500.0, np.ones(3), np.eye(3), 1.0, np.asarray(BT709_Y))
    >>> [round(float(v), 4) for v in srgb_to_camera(np.full((1, 1, 3), 0.5), c)[0, 0]]
    [0.107, 0.107, 0.107]
    """
    lin = srgb_eotf(np.asarray(srgb, dtype=np.float32))
    cam = apply_ccm(np.ascontiguousarray(lin, dtype=np.float32), np.linalg.inv(colour.ccm))
    return np.asarray(invert_luminance(cam, colour.gain, colour.luma_weights, tone, white), dtype=np.float32)


def process_after_slot(x, ccm, exposure_ev: float, *, luma_weights=BT709_Y, tone: str = "none",
                       white: float = 4.0, channel_axis: int = -1, gamma: bool = True):
    """``Process`` of the paper's loss (eq. 24, label "loss function"): the pipeline's stages after
    the correction slot — luminance, ccm, gamma (sRGB) — on numpy or torch.

    Parameters
    ----------
    x : array
        Balanced camera RGB: numpy ``(H, W, 3)`` or torch ``(N, 3, H, W)``
        (``channel_axis=-3``; one matrix for the batch).
    ccm : (3, 3) array_like
    exposure_ev : float
        Total exposure of the luminance stage.
    luma_weights, tone, white
        The luminance stage's settings (weights used only with a tone curve).
    gamma : bool
        False: stop before the sRGB curve (linear sRGB, not clipped).

    Returns
    -------
    array like x, display sRGB in [0, 1] (linear sRGB with ``gamma=False``).
    """
    gain = float(2.0 ** exposure_ev)
    y = apply_ccm(adjust_luminance(x, gain, luma_weights, tone, white, channel_axis=channel_axis), ccm,
                  channel_axis=channel_axis)
    return srgb_oetf(y) if gamma else y



def unprocess_after_slot(srgb, ccm, exposure_ev: float, *, luma_weights=BT709_Y, tone: str = "none",
                         white: float = 4.0, channel_axis: int = -1):
    """The inverse of :func:`process_after_slot` (numpy or torch): the
    balanced camera RGB that the stages after the slot turn into ``srgb``.
    Exact where nothing clipped; the target of a model trained "raw → raw",
    without the stages that follow it (the placement ablation).

    >>> x = np.full((1, 1, 3), 0.1, np.float32)
    >>> y = process_after_slot(x, np.eye(3), 1.0)
    >>> [round(float(v), 5) for v in unprocess_after_slot(y, np.eye(3), 1.0)[0, 0]]
    [0.1, 0.1, 0.1]
    """
    lin = apply_ccm(srgb_eotf(srgb), np.linalg.inv(np.asarray(ccm, dtype=np.float64)), channel_axis=channel_axis)
    return invert_luminance(lin, float(2.0 ** exposure_ev), luma_weights, tone, white, channel_axis=channel_axis)
