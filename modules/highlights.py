"""Highlights: what becomes of pixels where a camera channel reached its
clip level.

A raw channel at its white level records "at least this much", not the
light that fell on it. After white balance the three channels clip at
different levels (white × each channel's gain), so a clipped green beside
unclipped red and blue reads as magenta, the tint of blown skies and clouds
in a naive render. Two answers, chosen by ``mode``:

``clip`` (default)
    Pass-through. The ``dng_render`` stage clamps every camera channel at
    the camera white before its matrix, as Adobe's DNG SDK render does
    (``dng_render.cpp`` / ``RefBaselineABCtoRGB``: each channel
    ``min(value, camera white)``), so a clipped pixel comes out neutral
    white, the reference behaviour.
``reconstruct``
    Recovers the clipped channel from the channels that did not clip, by
    the "inpaint opposed" method (below), for renders that keep values above
    white: the ``linear`` look with a tone curve, a darker exposure,
    training data, ``dng_render`` with ``clip_white = false``. Under the
    default look the camera-white clamp that follows sets a reconstructed
    channel back to the clamp (it was raised from at least its clip level,
    which is not below the clamp), so there the two modes give the same
    picture but for channels just below their clip level (the threshold
    and slack of the Notes).

Method (``reconstruct``)
------------------------
Inpaint opposed, by H. Schwalm with garagecoder and Iain of the G'MIC team
for darktable 4.2 (2022, ``src/iop/hlreconstruct/opposed.c``; the
``_process_linear_opposed`` variant works on demosaiced RGB, as here) and
adopted by RawTherapee 5.10 as "Inpaint opposed". A clipped channel is
estimated as the mean of the two *opposed* channels, averaged in a cube-root
space, plus one global chrominance offset per channel measured on the
unclipped pixels around the clipped areas; the estimate only ever raises a
clipped value. Written here from the description and equations, with two
additions stated in the Notes: the clip level follows the lens-shading gain
over the frame, and pixels near full clipping are drawn to neutral.

Notes
-----
For balanced camera RGB :math:`x_c` (c ∈ {R, G, B}) with clip level
:math:`L_c(p) = t \\cdot W \\cdot g_c \\cdot s_c(p)` — threshold
:math:`t` (0.99 by default), white :math:`W = 1`, white-balance gain
:math:`g_c`, lens-shading gain :math:`s_c(p)` at pixel :math:`p` (from the
file's GainMaps where ``lens_shading`` applied them) — a channel is clipped
where :math:`x_c \\ge L_c`, or :math:`x_c \\ge (1 - \\delta) L_c`,
:math:`\\delta = 0.05`, within 3 px of a pixel at or above :math:`L_c` in
the same channel: inside a clipped area demosaicing and noise leave values
just below the level, which would stay tinted specks. With :math:`a, b` the
other two channels:

.. math::

    r_c = \\left(\\tfrac12\\left(x_a^{1/3} + x_b^{1/3}\\right)\\right)^3
    \\qquad\\text{(the opposed reference)}

    k_c = \\operatorname{mean}_{p \\in N_c}\\left(x_c - r_c\\right)
    \\qquad\\text{(chrominance offset; 0 if } |N_c| < 100)

    y_c = \\max\\left(x_c,\\ r_c + k_c\\right)\\ \\text{where clipped, else } x_c

:math:`N_c` holds the pixels within ``RING`` = 8 px of a pixel clipped in
:math:`c`, none of whose channels is clipped, with :math:`x_c > 0.2\\,L_c`
(darktable's bounds; it dilates a ⅓-scale mask), sampled every 4 px (a
mean needs no more).

Neutral near full clipping: where all three channels are clipped nothing
is known of the colour, and the opposed estimate of one clipped channel
from two others clipped at different levels is tinted. With
:math:`q = \\min_c \\min(x_c / L_c, 1)` (1 when every channel clipped) and
:math:`\\sigma = \\operatorname{smoothstep}((q - q_0) / (1 - q_0))`,
:math:`q_0 = 0.8`, every changed pixel becomes
:math:`y + \\sigma(\\max_c y_c - y)`: neutral at full clipping, the plain
estimate while the unclipped channels are below 80 % of their clip level.
No output channel is below its input.

=================  ==================  ====================================
array              shape               values
=================  ==================  ====================================
camera RGB in/out  (H, W, 3) float32   linear, balanced, white = 1 × gain
clip levels        (3,) and a field    as above; the field on a coarse grid
=================  ==================  ====================================

Pixels whose every channel is below :math:`(1 - \\delta) L_c` are returned
unchanged, bit for bit, in both modes; a frame without clipped pixels
comes back as the same array.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from isp.frame import Domain, Frame
from isp.stage import StageBase

__all__ = ["ClipLevels", "Highlights", "MODES", "clip_levels", "clipped_mask", "clipped_pixels",
           "reconstruct_opposed"]

#: what the stage can do with clipped pixels (see the module docstring)
MODES = ("clip", "reconstruct")
#: radius (px) of the ring around clipped areas where chrominance is measured
RING = 8
#: the ring is sampled every RING_GRID px in each direction
RING_GRID = 4
#: fewest ring pixels for a chrominance offset (else 0), as darktable
MIN_RING = 100
#: lower bound of ring values, as a fraction of the clip level (darktable)
RING_FLOOR = 0.2
#: how far below its level (a fraction) a channel near a clipped one still counts as clipped
SLACK = 0.05
#: ... within this many pixels (Chebyshev distance) of one at or above its level
GROW = 3
#: clip fraction of the least-clipped channel above which pixels go neutral
NEUTRAL_FROM = 0.8
#: points per row when the level field is sampled with cv2.remap
REMAP_COLS = 4096
#: the lens-shading field is evaluated on a grid FIELD_STEP times coarser than the frame
FIELD_STEP = 8
#: ... but with at least this many samples a side (fewer only where the frame is smaller)
FIELD_MIN = 256


@dataclass(frozen=True)
class ClipLevels:
    """The clip level of each balanced camera channel, over the frame.

    Attributes
    ----------
    levels : (3,) ndarray of float64
        Clip level of R, G, B where the lens-shading gain is 1: threshold ×
        white (1) × white-balance gain.
    field : (h, w, 3) ndarray of float32 or None
        Lens-shading gain per colour on a coarse grid of the full frame
        (active area); None where no shading was applied.
    scale : (float, float)
        Samples of ``field`` per full-frame pixel, vertically and
        horizontally.
    offset : ((float, float), ...)
        Per colour, where its sample 0 sits, in samples, measured as a
        pixel centre's position ``(pixel + 0.5) · scale``: 0.5 for samples
        centred on their cells; the CFA sites of a colour sit off the
        centre of the 2 × 2 block it samples.
    origin : (int, int)
        Data pixel (0, 0) in full-frame pixels (``CameraMeta.origin``).
    """

    levels: np.ndarray
    field: np.ndarray | None = None
    scale: tuple[float, float] = (1.0, 1.0)
    offset: tuple = ((0.5, 0.5),) * 3
    origin: tuple[int, int] = (0, 0)

    def floor(self) -> np.ndarray:
        """(3,) the lowest clip level of each channel anywhere in the frame."""
        if self.field is None:
            return np.asarray(self.levels, np.float64)
        return np.asarray(self.levels, np.float64) * self.field.reshape(-1, 3).min(axis=0)

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(K, 3) float32 clip levels at data pixels ``(rows[k], cols[k])``
        (the field interpolated bilinearly)."""
        lv = np.asarray(self.levels, np.float32)
        if self.field is None:
            return np.broadcast_to(lv, (len(rows), 3))
        oy, ox = self.origin
        sy, sx = self.scale
        k = len(rows)
        # cv2.remap samples (bilinear, edge samples held) at up to 32767 x 32767
        # points: lay the K points out as rows of REMAP_COLS
        n = -(-max(k, 1) // REMAP_COLS) * REMAP_COLS
        y = np.zeros(n, np.float32)
        x = np.zeros(n, np.float32)
        np.multiply(np.asarray(rows, np.float32) + np.float32(oy + 0.5), np.float32(sy), out=y[:k])
        np.multiply(np.asarray(cols, np.float32) + np.float32(ox + 0.5), np.float32(sx), out=x[:k])
        out = np.empty((k, 3), np.float32)
        for c in range(3):
            # where the samples of colour c sit, in sample units
            dy, dx = (np.float32(v) for v in self.offset[c])
            g = cv2.remap(np.ascontiguousarray(self.field[..., c]), (x - dx).reshape(-1, REMAP_COLS),
                          (y - dy).reshape(-1, REMAP_COLS), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
            out[:, c] = g.ravel()[:k] * lv[c]
        return out


def _shading_field(frame: Frame, step: int = FIELD_STEP) -> tuple | None:
    """Lens-shading gain per colour on a coarse grid of the full frame, or
    None if the frame's history shows no lens-shading gains applied.

    The ``lens_shading`` stage itself runs on a mosaic of ones up to
    ``step`` times smaller than the full frame (the active area): its
    opcodes place their maps by fractions of the image size, so the smaller
    image samples the same smooth field. Each colour takes the mean of its
    CFA sites. The stage's default parameters are assumed (full strength,
    DNG map sampling); a frame that was never a mosaic (a linear DNG) gets
    None.

    Returns
    -------
    (field, scale, offset) : (h, w, 3) float32 gains; (h, w) ÷ the full
        frame's (H, W); where each colour's samples sit (see
        :class:`ClipLevels`).
    """
    applied = [s for s in frame.history if s.stage == "lens_shading" and "gains" in s.note]
    meta = frame.meta
    if not applied or meta.cfa is None:
        return None
    from modules.lens_shading import LensShading

    fh, fw = frame.full_size
    # no coarser than FIELD_MIN samples a side (a small frame keeps its own size)
    h = 2 * max(1, round(max(fh / step, min(fh, FIELD_MIN)) / 2))
    w = 2 * max(1, round(max(fw / step, min(fw, FIELD_MIN)) / 2))
    oy, ox = meta.origin
    # the CFA phase at full-frame (0, 0), so each map lands on its colour
    cfa0 = meta.cfa.shifted(-oy, -ox)
    small = meta.replace(active_area=(0, 0, h, w), origin=(0, 0), cfa=cfa0)
    gains = LensShading()(Frame(np.ones((h, w), np.float32), Domain.RAW_LINEAR, small)).data
    field = np.zeros((h // 2, w // 2, 3), np.float32)
    count = np.zeros(3, np.float32)
    phase = np.zeros((3, 2))
    for i in range(2):
        for j in range(2):
            c = int(cfa0.pattern[i, j])
            field[..., c] += gains[i::2, j::2]
            count[c] += 1
            phase[c] += (i, j)
    # the sites of colour c sit at small-image pixels 2k + phase: centres (2k + phase + 0.5)
    offset = tuple(tuple((phase[c] / count[c] + 0.5) / 2) for c in range(3))
    return field / count, (h / 2 / fh, w / 2 / fw), offset


def clip_levels(frame: Frame, threshold: float = 0.99) -> ClipLevels:
    """Clip level of each channel of a white-balanced camera-RGB frame.

    White is 1 after ``black_level``; the ``white_balance`` stage multiplies
    channel c by ``1 / frame.neutral[c]``, and ``lens_shading`` by its gain
    field, which is evaluated here where the history shows it applied.

    Parameters
    ----------
    frame : Frame
        camera_rgb (or a 3-channel raw_linear frame).
    threshold : float
        Fraction of the white level at which a channel counts as clipped
        (see :class:`Highlights`).

    Returns
    -------
    ClipLevels
    """
    neutral = np.asarray(frame.neutral if frame.neutral is not None else (1.0, 1.0, 1.0), np.float64)
    levels = threshold / neutral
    shading = _shading_field(frame)
    if shading is None:
        return ClipLevels(levels, origin=frame.meta.origin)
    field, scale, offset = shading
    return ClipLevels(levels, field, scale, offset, frame.meta.origin)


def clipped_pixels(rgb: np.ndarray, clip: ClipLevels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels with a channel at or above its clip level.

    A channel counts as clipped at or above its level, and within
    :data:`SLACK` below it where a pixel within :data:`GROW` pixels is at or
    above it (demosaicing and noise leave values just below the level
    inside a clipped area).

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32
    clip : ClipLevels

    Returns
    -------
    index : (K,) ndarray of intp
        Flat pixel indices (row · W + col), ascending.
    clipped : (K, 3) ndarray of bool
        Which channels of those pixels are clipped.
    levels : (K, 3) ndarray of float32
        The clip levels at those pixels.
    """
    h, w, _ = rgb.shape
    low = (clip.floor() * (1.0 - SLACK)).astype(np.float32)
    # one pass over the frame: a pixel is free where every channel is below its lowest level
    below = np.nextafter(low, np.float32(-np.inf))
    free = cv2.inRange(rgb, (-np.inf,) * 3, tuple(float(v) for v in below))
    idx = np.flatnonzero(free == 0)
    if idx.size == 0:
        return idx, np.zeros((0, 3), bool), np.zeros((0, 3), np.float32)
    rows, cols = np.divmod(idx, w)
    lv = clip.at(rows, cols)
    v = rgb.reshape(-1, 3)[idx]
    m = v >= lv
    slack = (v >= lv * np.float32(1.0 - SLACK)) & ~m
    reach = np.ones((2 * GROW + 1, 2 * GROW + 1), np.uint8)
    for c in np.flatnonzero(slack.any(axis=0)):
        core = np.zeros(h * w, np.uint8)
        core[idx[m[:, c]]] = 1
        near = cv2.dilate(core.reshape(h, w), reach).ravel()[idx] > 0
        m[:, c] |= slack[:, c] & near
    keep = m[:, 0] | m[:, 1] | m[:, 2]
    return idx[keep], m[keep], lv[keep]


def clipped_mask(rgb: np.ndarray, clip: ClipLevels) -> np.ndarray:
    """(H, W, 3) bool: where each channel is at or above its clip level.

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32
    clip : ClipLevels
    """
    idx, m, _ = clipped_pixels(rgb, clip)
    out = np.zeros(rgb.shape, bool)
    out.reshape(-1, 3)[idx] = m
    return out


def _opposed(v: np.ndarray) -> np.ndarray:
    """(K, 3) opposed references: per channel, the cube of the mean cube
    root of the other two (negative values count as 0)."""
    cr = np.cbrt(np.maximum(v, 0.0, dtype=np.float32))
    s = (cr[:, 0] + cr[:, 1] + cr[:, 2])[:, None]
    return (0.5 * (s - cr)) ** 3


def _chrominance(rgb: np.ndarray, clip: ClipLevels, idx: np.ndarray, m: np.ndarray,
                 ring: int) -> np.ndarray:
    """(3,) offsets k_c: mean of ``x_c − r_c`` over the unclipped pixels
    within ``ring`` px of the pixels clipped in c, sampled on a grid of
    ``RING_GRID`` px (a mean needs no more; darktable works on a ⅓-scale
    mask)."""
    h, w, _ = rgb.shape
    g = RING_GRID
    gh, gw = -(-h // g), -(-w // g)
    rows, cols = np.divmod(idx, w)
    cell = (rows // g) * gw + cols // g
    reach = max(1, -(-ring // g))
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * reach + 1, 2 * reach + 1))
    near = np.zeros((3, gh * gw), np.uint8)
    for c in range(3):
        near[c, cell[m[:, c]]] = 1
        near[c] = cv2.dilate(near[c].reshape(gh, gw), kernel).ravel()
    sel = np.flatnonzero(near.any(axis=0))
    # the sample of each cell: its centre pixel (inside the frame)
    sr = np.minimum((sel // gw) * g + g // 2, h - 1)
    sc = np.minimum((sel % gw) * g + g // 2, w - 1)
    v = rgb[sr, sc]
    lv = clip.at(sr, sc)
    below = v < lv
    free = below[:, 0] & below[:, 1] & below[:, 2]
    ref = _opposed(v)
    out = np.zeros(3, np.float32)
    for c in range(3):
        use = free & (near[c, sel] > 0) & (v[:, c] > RING_FLOOR * lv[:, c])
        if use.sum() >= MIN_RING:
            out[c] = np.mean(v[use, c] - ref[use, c], dtype=np.float64)
    return out


def reconstruct_opposed(rgb: np.ndarray, clip: ClipLevels, *, ring: int = RING
                        ) -> tuple[np.ndarray, dict]:
    """Rebuild clipped channels from the unclipped ones (inpaint opposed).

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32
        Linear, white-balanced camera RGB, not clipped (values above the
        clip levels are kept).
    clip : ClipLevels
        Each channel's clip level (:func:`clip_levels`).
    ring : int
        Radius in pixels of the neighbourhood of clipped areas whose
        unclipped pixels give the chrominance offsets.

    Returns
    -------
    out : (H, W, 3) ndarray, float32
        ``rgb`` itself if nothing is clipped; otherwise a new array, equal
        to ``rgb`` wherever no channel is clipped, and with every channel
        ≥ its input where one is.
    info : dict
        ``pixels`` (how many had a clipped channel), ``clipped`` (per
        channel), ``chroma`` (the offsets :math:`k_c`).

    Notes
    -----
    The equations are in the module docstring.

    Examples
    --------
    A grey ramp balanced for a neutral (0.5, 1, 0.7): green clips at 1,
    red at 2, blue at 1/0.7; where only green clipped it is rebuilt from
    red and blue.

    >>> y = np.linspace(0.5, 1.3, 9, dtype=np.float32)
    >>> clip = ClipLevels(np.array([2.0, 1.0, 1 / 0.7]))
    >>> rgb = np.stack([y, np.minimum(y, 1.0), y], axis=-1)[None]
    >>> out, info = reconstruct_opposed(rgb, clip)
    >>> [round(float(v), 2) for v in out[0, :, 1]]
    [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3]
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be (H, W, 3), got shape {rgb.shape}")
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    idx, m, lv = clipped_pixels(rgb, clip)
    info = {"pixels": int(idx.size), "clipped": [int(v) for v in m.sum(axis=0)],
            "chroma": [0.0, 0.0, 0.0]}
    if idx.size == 0:
        return rgb, info
    chroma = _chrominance(rgb, clip, idx, m, ring)
    info["chroma"] = [float(k) for k in chroma]

    v = rgb.reshape(-1, 3)[idx]
    y = np.where(m, np.maximum(v, _opposed(v) + chroma), v)
    f = v / lv
    q = np.minimum(np.minimum(np.minimum(f[:, 0], f[:, 1]), f[:, 2]), 1.0)[:, None]
    t = np.clip((q - NEUTRAL_FROM) / (1.0 - NEUTRAL_FROM), 0.0, 1.0)
    top = np.maximum(np.maximum(y[:, 0], y[:, 1]), y[:, 2])[:, None]
    y += t * t * (3.0 - 2.0 * t) * (top - y)

    out = rgb.copy()
    out.reshape(-1, 3)[idx] = y
    return out, info


@dataclass(frozen=True)
class Highlights(StageBase):
    """Clipped highlights: left for ``dng_render`` to make neutral
    (``clip``), or rebuilt from the unclipped channels (``reconstruct``).

    Parameters
    ----------
    mode : {"clip", "reconstruct"}
        See the module docstring.
    threshold : float
        Fraction of the white level at which a channel counts as clipped,
        in (0, 1] (and up to 5 % below it within 3 px of a clipped pixel:
        inside a clipped area demosaicing and noise leave values just below
        the level; Malvar–He–Cutler adds the other channels' Laplacian and
        their noise). Below 1 by default because the lens-shading gain that
        scales the level is evaluated on a coarse grid and the two green
        phases' maps differ by up to a few tenths of a per cent; darktable
        uses 0.987 on the mosaic. Some sensors saturate further below the
        WhiteLevel their files declare (the GoPro HERO6 and FUSION green at
        0.951 of 16383): lower it to reach them. Used by ``reconstruct``.
    """

    name = "highlights"
    consumes = (Domain.CAMERA_RGB,)

    mode: Literal["clip", "reconstruct"] = "clip"
    threshold: float = 0.99

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r}; valid: {', '.join(MODES)}")
        if not (math.isfinite(self.threshold) and 0.0 < self.threshold <= 1.0):
            raise ValueError(f"threshold must be in (0, 1], got {self.threshold}")

    def process(self, frame: Frame) -> Frame:
        if self.mode == "clip":
            return frame.evolve(stage=self.name, note="clip (clipped channels are made neutral "
                                                      "by the camera-white clamp of dng_render)")
        clip = clip_levels(frame, self.threshold)
        out, info = reconstruct_opposed(frame.data, clip)
        lv = ", ".join(f"{v:.3f}" for v in clip.levels)
        if info["pixels"] == 0:
            note = f"reconstruct: nothing clipped (levels {lv})"
        else:
            k = ", ".join(f"{v:+.3f}" for v in info["chroma"])
            n = frame.data.shape[0] * frame.data.shape[1]
            note = (f"reconstruct: {info['pixels']} px ({100 * info['pixels'] / n:.2f} %) with a clipped "
                    f"channel, levels {lv}{' x lens shading' if clip.field is not None else ''}, "
                    f"chrominance {k}")
        return frame.evolve(out, stage=self.name, note=note)
