"""Evaluation of a correction model on proxy cameras it was not trained on:
PSNR and SSIM per field ring, for the uncorrected pipeline, the model and
a classical non-blind deconvolution (paper, section 5.3; ``isp eval``).

Test set
--------
The test set is synthesised by the training data's own chain
(:mod:`restoration.synth.pairs`: latent sRGB → camera RGB with a real phone's
colour model → blur by the PSF map of a lens → Bayer sampling, noise →
the pipeline's white balance and demosaic → ``J``), with three
differences:

* **Unseen proxy cameras.** ``samples`` lenses are drawn within tolerance
  around the proxy (:func:`restoration.synth.optics.draw_lenses`, same
  tolerances and refocusing as training) from
  ``SeedSequence(seed, spawn_key=(2,))``. Training draws its lenses from
  ``spawn_key=(0,)`` (and its pairs from ``(1, i)``), so for any pair of
  seeds the two streams are independent: an evaluation lens coincides with
  a training lens with probability 0, and the report checks the PSF-map
  keys against any the model's metadata lists. The proxy itself (the
  "single sample" training lens) is added only with ``with_proxy``.
* **Placed on the field rings.** Each latent image's centre crop is placed
  at ``positions`` points of every ring, at the ring's nominal radius and
  a random angle among those where the crop fits on the sensor (paired
  design: every lens sees the same crops at the same places, and a crop
  differs between rings only by where it lies).
* **A scored core.** The crop synthesised and corrected is ``size + 2 ×
  border`` pixels; only its central ``size × size`` core is scored, so
  neither the model's nor the deconvolution's border handling is (the
  pipeline runs whole frames, where a crop's border is an interior).

Field rings
-----------
The normalised field radius of a pixel is its distance from the frame
centre over the half-diagonal (``r = 1`` at the corners; pixel centres at
``+½``), i.e. the image height relative to the corner, not the elliptical
radius of the field channels. Rings (:data:`RINGS`): ``"0.1"`` = ``r ∈
[0, 0.2)``, ``"0.5"`` = ``[0.4, 0.6)``, ``"0.9"`` = ``[0.8, 1]``. A crop
contributes to a ring when at least ``min_ring_pixels`` of its core lie
in it (on a phone sensor a 256-px crop spans ≈ 0.07 of the radius, so each
crop falls in one ring).

Metrics
-------
On display sRGB: ``Process(x)`` = the pipeline's stages after the slot in
the ``linear`` look, on which the correction is trained
(:func:`restoration.synth.colour.process_after_slot`, the pair's CCM and
exposure, clipped to [0, 1] by the sRGB encoding) against the latent
sRGB target, for ``x = J`` (uncorrected), ``Model(J)`` (corrected) and the
deconvolution of ``J`` (baseline).

* PSNR = ``10 log10(1 / MSE)`` over the pixels (all three channels) of the
  crop's core, or of its part in a ring; capped at 100 dB (MSE ≥ 1e-10).
* SSIM (Wang et al. 2004): :func:`skimage.metrics.structural_similarity`
  with an 11 × 11 Gaussian window (σ = 1.5), population covariances,
  ``data_range = 1``, per channel; the SSIM map of the whole synthesised
  crop is averaged over the same pixels (so the window never meets the
  crop's border).
* A ring's (or an image's) figure is the mean over its crops.

References
----------
* Z. Wang, A. C. Bovik, H. R. Sheikh, E. P. Simoncelli, "Image quality
  assessment: from error visibility to structural similarity", IEEE TIP
  13(4), 600–612, 2004.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from isp.errors import ConfigError, InputError
from modules.gamma import srgb_oetf

from restoration.evaluate.baseline import BASELINES, deconvolve, noise_variance, quantisation_step
from restoration.synth.pairs import (
    SynthPlan,
    SynthSettings,
    crop_blur,
    read_latent,
    seeded_rng,
    sensor_geometry,
    find_latents,
    usable_latents,
)
from restoration.synth.colour import draw_colour, process_after_slot, srgb_to_camera
from restoration.synth.optics import psf_options as _psf_options
from restoration.synth.optics import window_reach_px
from restoration.synth.sensor import capture_mosaic, develop, sensor_model

__all__ = ["RINGS", "SCHEMA", "EvalSettings", "eval_plan", "evaluate", "evaluate_plan", "field_radius",
           "ring_origin"]

SCHEMA = "isp-eval/v1"
#: field rings: name → [low, high) of the normalised radius (the last one closed)
RINGS = {"0.1": (0.0, 0.2), "0.5": (0.4, 0.6), "0.9": (0.8, 1.0)}
#: spawn keys of the evaluation's random streams (training uses 0: lenses, 1: pairs)
KEY_LENSES, KEY_COLOUR, KEY_NOISE, KEY_PLACE = 2, 3, 4, 5
#: SSIM settings (Wang et al. 2004)
SSIM = {"gaussian_weights": True, "sigma": 1.5, "use_sample_covariance": False, "data_range": 1.0}
VARIANTS = ("uncorrected", "corrected", "baseline")
PSNR_CAP_MSE = 1e-10


@dataclass(frozen=True)
class EvalSettings:
    """What an evaluation covers (its lenses, the synthesis overrides) and
    how crops are placed and scored. Checked at construction
    (:class:`isp.errors.ConfigError` naming the field and value).

    Parameters
    ----------
    size : int
        Side of the scored core, px (even).
    border : int
        Context synthesised and corrected around the core, px (even, ≥ 0).
    positions : int
        Placements per ring and image.
    baseline : {"wiener", "rl", "none"}
        Classical deconvolution (:mod:`restoration.evaluate.baseline`).
    rings : dict
        Name → (low, high) normalised radius.
    min_ring_pixels : int
        Core pixels a crop needs in a ring to count for it.
    samples : int
        Lenses drawn within tolerance, unseen in training, ≥ 0
        (:func:`eval_lenses`; 0 needs ``with_proxy``).
    seed : int
        Seed of the lenses, colours, noise and placements.
    tolerance_scale : float
        The drawn lenses' tolerances, × the defaults, > 0.
    with_proxy : bool
        Evaluate the proxy lens itself too.
    noise : bool, optional
        Override of the synthesis's ``noise`` (None: the training's).
    exposure_ev : (low, high), optional
        Override of the synthesis's ``exposure_ev`` (luminosity
        compression, EV): the test set at other light levels than
        training's.
    noise_scale : (low, high), optional
        Override of the synthesis's ``noise_scale`` (factor on the
        NoiseProfile, > 0).
    """

    size: int = 256
    border: int = 32
    positions: int = 1
    baseline: str = "wiener"
    rings: dict = field(default_factory=lambda: dict(RINGS))
    min_ring_pixels: int = 256
    samples: int = 4
    seed: int = 0
    tolerance_scale: float = 1.0
    with_proxy: bool = False
    noise: bool | None = None
    exposure_ev: tuple[float, float] | None = None
    noise_scale: tuple[float, float] | None = None

    def __post_init__(self):
        if not (int(self.samples) == self.samples and self.samples >= 0):
            raise ConfigError(f"EvalSettings.samples: must be an integer ≥ 0, got {self.samples!r}")
        if not (float(self.tolerance_scale) > 0):
            raise ConfigError(f"EvalSettings.tolerance_scale: must be > 0, got {self.tolerance_scale!r}")
        for name in ("exposure_ev", "noise_scale"):
            v = getattr(self, name)
            if v is not None:
                try:
                    lo, hi = (float(x) for x in v)
                except (TypeError, ValueError):
                    raise ConfigError(f"EvalSettings.{name}: must be (low, high), got {v!r}") from None
                if not lo <= hi or (name == "noise_scale" and lo <= 0):
                    raise ConfigError(f"EvalSettings.{name}: need {'0 < ' if name == 'noise_scale' else ''}"
                                      f"low ≤ high, got {v!r}")
                object.__setattr__(self, name, (lo, hi))
        if not (int(self.size) == self.size and self.size >= 16 and self.size % 2 == 0):
            raise ConfigError(f"size must be an even integer ≥ 16, got {self.size!r}")
        if not (int(self.border) == self.border and self.border >= 0 and self.border % 2 == 0):
            raise ConfigError(f"border must be an even integer ≥ 0, got {self.border!r}")
        if not (int(self.positions) == self.positions and self.positions >= 1):
            raise ConfigError(f"positions must be an integer ≥ 1, got {self.positions!r}")
        if self.baseline not in BASELINES:
            raise ConfigError(f"unknown baseline {self.baseline!r}; valid: {', '.join(BASELINES)}")
        for name, (lo, hi) in self.rings.items():
            if not 0.0 <= lo < hi <= 1.0:
                raise ConfigError(f"ring {name!r}: need 0 ≤ low < high ≤ 1, got ({lo}, {hi})")

    @property
    def work(self) -> int:
        """Side of the synthesised and corrected crop."""
        return self.size + 2 * self.border


#: the EvalSettings fields of how crops are placed and scored (the report's "settings"; the
#: lenses and synthesis overrides are reported under "lens" and "synth")
_SCORING = ("size", "border", "positions", "baseline", "rings", "min_ring_pixels")


# -- geometry -------------------------------------------------------------------------------

def field_radius(rows, cols, full_size) -> np.ndarray:
    """Normalised field radius of pixels ``rows × cols`` of a frame: distance
    of the pixel centre from the frame centre over the half-diagonal.

    Returns
    -------
    (h, w) float64 ndarray, 0 at the centre, 1 at the corners.

    >>> float(field_radius(np.array([0]), np.array([0]), (2, 2))[0, 0])
    0.5
    """
    fh, fw = (float(v) for v in full_size)
    y = np.asarray(rows, dtype=np.float64) + 0.5 - fh / 2.0
    x = np.asarray(cols, dtype=np.float64) + 0.5 - fw / 2.0
    return np.hypot(y[:, None], x[None, :]) / math.hypot(fh / 2.0, fw / 2.0)


def ring_origin(full_size, work: int, radius: float, band: tuple[float, float], rng,
                candidates: int = 360) -> tuple[int, int]:
    """Top-left pixel of a ``work × work`` crop centred near normalised
    field radius ``radius`` at a random angle, inside the frame.

    Among ``candidates`` equally spaced angles (random phase), the crop is
    put at ``radius`` and moved inside the frame; one is drawn among those
    lying wholly in ``band``, else among those whose centre is in it, else
    the one whose centre is closest to ``radius`` (a frame too small for
    the ring).
    """
    fh, fw = (int(v) for v in full_size)
    if work > fh or work > fw:
        raise ConfigError(f"crops of {work} px do not fit the {fh}×{fw} frame")
    hy, hx = fh / 2.0, fw / 2.0
    half_diag = math.hypot(hy, hx)
    theta = rng.uniform(0.0, 2.0 * math.pi) + np.arange(candidates) * (2.0 * math.pi / candidates)
    r0 = np.clip(np.rint(hy + radius * half_diag * np.sin(theta) - work / 2.0), 0, fh - work).astype(int)
    c0 = np.clip(np.rint(hx + radius * half_diag * np.cos(theta) - work / 2.0), 0, fw - work).astype(int)
    # pixel-centre extent of each crop relative to the frame centre
    y0, y1 = r0 + 0.5 - hy, r0 + work - 0.5 - hy
    x0, x1 = c0 + 0.5 - hx, c0 + work - 0.5 - hx
    centre = np.hypot(0.5 * (y0 + y1), 0.5 * (x0 + x1)) / half_diag
    near = np.hypot(np.clip(0.0, y0, y1), np.clip(0.0, x0, x1)) / half_diag
    far = np.hypot(np.maximum(np.abs(y0), np.abs(y1)), np.maximum(np.abs(x0), np.abs(x1))) / half_diag
    lo, hi = band
    for ok in ((near >= lo) & (far <= hi), (centre >= lo) & (centre <= hi)):
        idx = np.nonzero(ok)[0]
        if idx.size:
            k = int(idx[rng.integers(idx.size)])
            break
    else:
        k = int(np.argmin(np.abs(centre - radius)))
    return int(r0[k]), int(c0[k])


# -- the test set ---------------------------------------------------------------------------

def _margin_before_maps(lens, psf_options: dict) -> int:
    return window_reach_px(psf_options["n"], psf_options.get("pitch_um"), lens.nominal.sensor.pixel_pitch_um) + 4


def eval_lenses(lens, samples: int, seed: int, *, tolerance_scale: float = 1.0, with_proxy: bool = False) -> list:
    """The evaluation's lenses: ``samples`` drawn within tolerance from
    ``SeedSequence(seed, spawn_key=(2,))`` (disjoint from training's
    ``(0,)``), preceded by the proxy itself when ``with_proxy``."""
    from restoration.synth.optics import draw_lenses

    if int(samples) < 0:
        raise ConfigError(f"samples must be ≥ 0, got {samples}")
    if int(samples) == 0 and not with_proxy:
        raise ConfigError("no lens to evaluate: samples = 0 needs with_proxy")
    drawn = draw_lenses(lens, int(samples) + 1, seeded_rng(seed, KEY_LENSES), tolerance_scale=tolerance_scale)[1:]
    return ([lens] if with_proxy else []) + drawn


def eval_plan(lens, images_dir, settings: EvalSettings | None = None, *, synth: SynthSettings | None = None,
              cameras=None, psf_options: dict | None = None, cache_dir=None, executor=None) -> SynthPlan:
    """Read the inputs and compute (or read from the cache) the PSF maps of
    the unseen lenses.

    Parameters
    ----------
    lens : path or PerturbedLens
        The proxy camera the model was trained for.
    images_dir : path
        Latent sRGB test images (searched recursively); each must hold a
        crop of ``settings.work`` plus the blur's context.
    settings : EvalSettings
        The crops and the lenses (``samples`` drawn within tolerance, unseen
        in training, from ``seed``; module notes).
    synth : SynthSettings, optional
        Colour, exposure and noise ranges, demosaic, tone (``size`` is
        replaced by ``settings.work``; ``augment`` is off). Default: the
        training defaults.
    cameras : sequence of path, optional
        Phone DNGs for the colour models (default ``isp synth``'s).
    psf_options : dict, optional
        :class:`calibration.optics.psf.map.PSFMapSettings` fields (grid, n, ...),
        as the training set's.
    cache_dir : path, optional
        PSF-map cache (default ``$ISP_CACHE/psf`` or ``~/.cache/phone-isp/psf``).
    executor : isp.runtime.executor.Executor, optional
        Runs the PSF maps' regions (default psf_map's).
    """
    from dataclasses import replace

    from restoration.synth.defaults import DATA, DEFAULT_CAMERAS
    from restoration.synth.colour import colour_table, read_camera
    from restoration.synth.optics import load_lens, psf_maps
    from restoration.synth.sensor import DEFAULT_NOISE_PROFILE, noise_profile_of

    settings = settings or EvalSettings()
    synth = replace(synth or SynthSettings(), size=settings.work, augment=False)
    lens_path = None
    if isinstance(lens, (str, os.PathLike)):
        lens_path = str(lens)
        lens = load_lens(lens)
    opts = _psf_options(psf_options)
    files = find_latents(images_dir)
    latents = usable_latents(files, settings.work + 2 * _margin_before_maps(lens, opts), images_dir)
    cams = tuple(read_camera(p) for p in (cameras or [DATA / c for c in DEFAULT_CAMERAS]))
    samples, seed, with_proxy = settings.samples, settings.seed, settings.with_proxy
    tolerance_scale = settings.tolerance_scale
    lenses = eval_lenses(lens, samples, seed, tolerance_scale=tolerance_scale, with_proxy=with_proxy)
    maps = tuple(psf_maps(lenses, executor=executor, cache_dir=cache_dir, **opts))
    sensor = maps[0].sensor
    prof = noise_profile_of(cams[0].meta)
    info = {
        "lens": {"path": lens_path, "name": lens.nominal.name, "samples": int(samples),
                 "with_proxy": bool(with_proxy), "tolerance_scale": float(tolerance_scale),
                 "draw": f"restoration.synth.optics.draw_lenses from SeedSequence({int(seed)}, spawn_key=(2,)); "
                         "training draws from spawn_key=(0,)",
                 "lenses": [{"proxy": bool(with_proxy and i == 0),
                             "perturbation": {k: v for k, v in sorted(pl.perturbation.as_dict().items()) if v},
                             "psf_map_key": mp.key} for i, (pl, mp) in enumerate(zip(lenses, maps))]},
        "psf_map": maps[0].settings,
        "skipped_images": sorted(str(f) for f in set(map(str, files)) - set(map(str, latents))),
    }
    colours = colour_table(list(cams), synth.cct_k, synth.cct_steps)
    return SynthPlan(maps, cams, colours, tuple(str(p) for p in latents), (sensor.height_px, sensor.width_px),
                     int(seed), synth, prof or DEFAULT_NOISE_PROFILE, info)


def _centre_crop(img: np.ndarray, side: int, path=None) -> np.ndarray:
    h, w = img.shape[:2]
    if h < side or w < side:
        raise InputError(path, f"latent image {h}×{w} is smaller than a crop with its context ({side}×{side})")
    r, c = (h - side) // 2, (w - side) // 2
    return img[r:r + side, c:c + side]


def synth_crop(plan: SynthPlan, k_lens: int, latent: np.ndarray, origin: tuple[int, int], colour,
               noise_profile, rng) -> tuple[np.ndarray, np.ndarray]:
    """One evaluation crop, synthesised as :func:`restoration.synth.pairs.make_pair`
    does a pair but at a chosen place, colour and noise.

    Parameters
    ----------
    plan : SynthPlan
    k_lens : int
        Lens (PSF map) index.
    latent : (n + 2m, n + 2m, 3) uint8/uint16 ndarray
        Latent sRGB with the plan's context margin ``m``, ``n =
        plan.settings.size``.
    origin : (row, col)
        Sensor pixel of the crop's first (non-margin) pixel.
    colour : PairColour
    noise_profile : (S, O)
    rng : numpy Generator
        Noise.

    Returns
    -------
    J : (n, n, 3) float32, the correction slot's input;
    target : (n, n, 3) float32, the latent sRGB in [0, 1].
    """
    st = plan.settings
    m, n = plan.margin, st.size
    work_origin = (origin[0] - m, origin[1] - m)
    srgb = latent.astype(np.float32) * np.float32(1.0 / np.iinfo(latent.dtype).max)
    cam = srgb_to_camera(srgb, colour, tone=st.tone, white=st.white)
    cam *= colour.neutral.astype(np.float32)
    psfmap = plan.maps[k_lens]
    blurred = cam if psfmap is None else crop_blur(plan, k_lens)(cam, work_origin)
    sensor = sensor_model(plan.cameras[0].meta, sensor_geometry(plan), noise_profile)
    mos = capture_mosaic(blurred, sensor, work_origin, rng, noise=st.noise, quantise=st.quantise)
    rgb = develop(mos, sensor.cfa.shifted(*work_origin), colour.neutral, st.demosaic)
    return rgb[m:m + n, m:m + n], srgb[m:m + n, m:m + n]


# -- scoring ----------------------------------------------------------------------------------

def _psnr(sq: np.ndarray) -> float:
    return float(10.0 * math.log10(1.0 / max(float(sq.mean(dtype=np.float64)), PSNR_CAP_MSE)))


def _scores(out: np.ndarray, target: np.ndarray, inner: slice, radius: np.ndarray, settings: EvalSettings) -> dict:
    """PSNR/SSIM of one processed crop: over the core, and per ring."""
    from skimage.metrics import structural_similarity

    _, smap = structural_similarity(target, out, channel_axis=-1, full=True, **SSIM)
    sq = ((out[inner, inner] - target[inner, inner]) ** 2).mean(axis=2)
    ss = smap[inner, inner].mean(axis=2)
    res = {"psnr": _psnr(sq), "ssim": float(ss.mean(dtype=np.float64)), "rings": {}}
    last = list(settings.rings)[-1]
    for name, (lo, hi) in settings.rings.items():
        mask = (radius >= lo) & ((radius <= hi) if name == last else (radius < hi))
        npx = int(mask.sum())
        if npx >= settings.min_ring_pixels:
            res["rings"][name] = {"psnr": _psnr(sq[mask]), "ssim": float(ss[mask].mean(dtype=np.float64)),
                                  "pixels": npx}
    return res


def _mean(values) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def _summary(records: list[dict], variants) -> dict:
    out = {"crops": len(records)}
    for v in VARIANTS:
        have = v in variants
        out[f"psnr_{v}"] = _mean(r[v]["psnr"] for r in records) if have and records else None
        out[f"ssim_{v}"] = _mean(r[v]["ssim"] for r in records) if have and records else None
    return out


def _training_keys(meta) -> set[str]:
    """Every ``psf_map_key`` found in a model's metadata (a training manifest
    carried by the checkpoint), recursively."""
    keys: set[str] = set()

    def walk(x):
        if isinstance(x, dict):
            for k, v in x.items():
                if k == "psf_map_key" and isinstance(v, str):
                    keys.add(v)
                else:
                    walk(v)
        elif isinstance(x, (list, tuple)):
            for v in x:
                walk(v)

    walk(meta)
    return keys


def training_pitches(meta) -> set[float]:
    """The pixel pitches (µm) of the PSF maps a model's training pairs were
    made with, from its metadata (``training_sets[*].psf_map.sensor``, at
    the top or under ``metadata`` as a checkpoint keeps it); empty where
    it does not say (an ONNX export).

    >>> training_pitches({"metadata": {"training_sets": [{"psf_map": {"sensor": {"pixel_pitch_um": 2.807}}}]}})
    {2.807}
    """
    if not isinstance(meta, dict):
        return set()
    sets = meta.get("training_sets") or (meta.get("metadata") or {}).get("training_sets") or []
    out = set()
    for t in sets:
        p = (((t or {}).get("psf_map") or {}).get("sensor") or {}).get("pixel_pitch_um")
        if isinstance(p, (int, float)):
            out.add(float(p))
    return out


def evaluate_plan(plan: SynthPlan, runner, settings: EvalSettings | None = None, *, executor=None) -> dict:
    """Score a model on a plan's lenses and images (module notes).

    Parameters
    ----------
    plan : SynthPlan
        From :func:`eval_plan` (``plan.settings.size`` must be
        ``settings.work``); a map may be None (an ideal lens).
    runner : callable
        ``runner(J, origin, full_size) -> (h, w, 3)`` (:mod:`restoration.evaluate.runner`).
    settings : EvalSettings
    executor : isp.runtime.executor.Executor, optional
        Its progress bar counts the crops (default: a bar on stderr); the
        crops run in this process, one after the other.

    Returns
    -------
    dict: ``rings`` (per ring: ``psnr_/ssim_`` ``uncorrected``,
    ``corrected``, ``baseline`` (None without a baseline), ``crops``,
    ``r_range``), ``overall``, ``per_image``, ``per_lens``, ``crops`` (one
    record per crop) and ``timing`` (seconds).
    """
    from isp.runtime.executor import create_executor

    settings = settings or EvalSettings()
    ex = create_executor("serial", progress=True) if executor is None else executor
    st = plan.settings
    if st.size != settings.work:
        raise ConfigError(f"the plan synthesises {st.size}-px crops; these settings need {settings.work} "
                          f"(size {settings.size} + 2 × border {settings.border})")
    variants = VARIANTS if settings.baseline != "none" else VARIANTS[:2]
    domain = (getattr(runner, "meta", None) or {}).get("domain")
    at_end = domain == "display_rgb"
    linear_srgb = domain == "linear_rgb"  # between the colour matrix and the gamma
    full = plan.full_size
    m, work = plan.margin, settings.work
    inner = slice(settings.border, settings.border + settings.size)
    ring_names = list(settings.rings)
    sensor = sensor_model(plan.cameras[0].meta, sensor_geometry(plan), plan.noise_profile)
    qstep = quantisation_step(sensor.white_level, sensor.black_level) if st.quantise else 0.0
    timing = dict.fromkeys(("synth", "model", "baseline", "metrics"), 0.0)
    records = []
    total = len(plan.latents) * len(plan.maps) * len(ring_names) * settings.positions
    t_all = time.perf_counter()
    with ex.bar(total=total, desc="eval", unit="crop") as bar:
        for i, path in enumerate(plan.latents):
            latent = _centre_crop(read_latent(path), work + 2 * m, path)
            crng = seeded_rng(plan.seed, KEY_COLOUR, i)
            colour = draw_colour(plan.colours, crng, exposure_ev=st.exposure_ev)
            lo, hi = st.noise_scale
            k_noise = float(math.exp(crng.uniform(math.log(lo), math.log(hi))))
            s0, o0 = plan.noise_profile
            profile = (k_noise * s0, k_noise * k_noise * o0)

            def process(x, colour=colour, gamma=True):
                return np.asarray(process_after_slot(x, colour.ccm, colour.exposure_ev,
                                                     luma_weights=colour.luma_weights, tone=st.tone,
                                                     white=st.white, gamma=gamma), dtype=np.float32)

            for j, ring in enumerate(ring_names):
                lo_r, hi_r = settings.rings[ring]
                for p in range(settings.positions):
                    origin = ring_origin(full, work, 0.5 * (lo_r + hi_r), (lo_r, hi_r),
                                         seeded_rng(plan.seed, KEY_PLACE, i, j, p))
                    rows = np.arange(settings.size) + origin[0] + settings.border
                    cols = np.arange(settings.size) + origin[1] + settings.border
                    radius = field_radius(rows, cols, full)
                    for k in range(len(plan.maps)):
                        t0 = time.perf_counter()
                        J, target = synth_crop(plan, k, latent, origin, colour, profile,
                                               seeded_rng(plan.seed, KEY_NOISE, i, k, j, p))
                        t1 = time.perf_counter()
                        if at_end:  # an sRGB → sRGB model: fed the processed input, scored as it is
                            corrected = np.clip(np.asarray(runner(process(J), origin, full), dtype=np.float32),
                                                0.0, 1.0)
                        elif linear_srgb:  # fed linear sRGB, its output encoded by the gamma stage
                            corrected = np.asarray(srgb_oetf(np.asarray(
                                runner(process(J, gamma=False), origin, full), dtype=np.float32)), dtype=np.float32)
                        else:
                            corrected = np.asarray(runner(J, origin, full), dtype=np.float32)
                        if corrected.shape != J.shape:
                            raise ConfigError(f"the model returned shape {corrected.shape} for an input of {J.shape}")
                        t2 = time.perf_counter()
                        outs = {"uncorrected": J, "corrected": corrected}
                        balance = None
                        if settings.baseline != "none":
                            if plan.maps[k] is None:      # an ideal lens: nothing to deconvolve
                                outs["baseline"] = J
                            else:
                                sigma2 = noise_variance(J, profile if st.noise else (0.0, 0.0), colour.neutral, qstep)
                                outs["baseline"], rec = deconvolve(
                                    J, crop_blur(plan, k).bank, origin, full, method=settings.baseline,
                                    sigma2=sigma2, blend=st.blend)
                                balance = rec.balance
                        t3 = time.perf_counter()
                        scores = {v: _scores(outs[v] if ((at_end or linear_srgb) and v == "corrected")
                                             else process(outs[v]),
                                             target, inner, radius, settings) for v in variants}
                        t4 = time.perf_counter()
                        timing["synth"] += t1 - t0
                        timing["model"] += t2 - t1
                        timing["baseline"] += t3 - t2
                        timing["metrics"] += t4 - t3
                        records.append({"image": i, "lens": k, "ring": ring, "position": p,
                                        "origin": [int(origin[0]) + settings.border, int(origin[1]) + settings.border],
                                        "radius": [float(radius.min()), float(radius.max())],
                                        "balance": balance,
                                        **{v: scores[v] for v in variants}})
                        bar.update()
    timing["total"] = time.perf_counter() - t_all
    n = max(len(records), 1)
    mpix = len(records) * work * work / 1e6
    timing["per_crop"] = timing["total"] / n
    timing["model_ms_per_mpix"] = 1e3 * timing["model"] / mpix if mpix else None

    rings = {}
    for name in ring_names:
        sub = [{v: r[v]["rings"][name] for v in variants} for r in records if name in r["uncorrected"]["rings"]]
        rings[name] = {"r_range": list(settings.rings[name]), **_summary(sub, variants),
                       "pixels": int(sum(s["uncorrected"]["pixels"] for s in sub))}
    root = Path(os.path.commonpath(plan.latents)) if len(plan.latents) > 1 else Path(plan.latents[0]).parent
    per_image = {os.path.relpath(path, root): _summary([r for r in records if r["image"] == i], variants)
                 for i, path in enumerate(plan.latents)}
    lens_info = plan.info.get("lens", {}).get("lenses") or [{} for _ in plan.maps]
    per_lens = [{**({"psf_map_key": li.get("psf_map_key")} if li.get("psf_map_key") else {}),
                 **({"proxy": li["proxy"]} if "proxy" in li else {}),
                 **_summary([r for r in records if r["lens"] == k], variants)}
                for k, li in enumerate(lens_info)]
    crops = [{"image": r["image"], "lens": r["lens"], "ring": r["ring"], "position": r["position"],
              "origin": r["origin"], "radius": r["radius"], "balance": r["balance"],
              **{f"{m_}_{v}": r[v][m_] for v in variants for m_ in ("psnr", "ssim")}} for r in records]
    return {"rings": rings, "overall": _summary(records, variants), "per_image": per_image,
            "per_lens": per_lens, "crops": crops, "timing": timing}


def evaluate(model, images_dir, lens, settings: EvalSettings | None = None, *, synth: SynthSettings | None = None,
             cameras=None, psf_options: dict | None = None, cache_dir=None, threads: int = 2,
             executor=None, device=None) -> dict:
    """Evaluate a model file on ``images_dir`` × ``samples`` proxy cameras not
    seen in training (module notes).

    Parameters
    ----------
    model : path or runner
        A checkpoint (:func:`restoration.nn.checkpoint.load_model`) or an
        ``.onnx`` export (:mod:`restoration.evaluate.runner`), or a runner.
    images_dir : path
        Latent sRGB test images.
    lens : path or PerturbedLens
        The proxy camera's lens file (or fitted proxy file).
    settings : EvalSettings, optional
        The unseen lenses (``samples``, ``seed``, ``tolerance_scale``,
        ``with_proxy``: :func:`eval_lenses`), the crops (``size``,
        ``border``, ``positions``, ``baseline``) and the overrides of
        ``synth`` (``noise``, ``exposure_ev``, ``noise_scale``).
    synth : SynthSettings, optional
        Colour, exposure, noise, demosaic, tone (:func:`eval_plan`);
        default the training defaults with the tone curve and white point
        of the model's metadata ``process``.
    cameras, psf_options, cache_dir
        :func:`eval_plan`.
    threads : int
        onnxruntime threads (a kernel setting, ≥ 1).
    executor : isp.runtime.executor.Executor, optional
        Runs the PSF maps' regions and shows progress (default: up to 2
        worker processes, with progress bars).
    device : isp.io.device.DeviceCalibration, optional
        The device calibration a model conditioned on the device reads
        (:mod:`restoration.evaluate.runner`); with a model file only.

    Returns
    -------
    dict, JSON-ready: ``schema``, ``model``, ``images``, ``lens``,
    ``settings``, ``rings``, ``overall``, ``per_image``, ``per_lens``,
    ``crops``, ``timing``; with ``device``, ``device`` (its lens, basis and
    source).
    """
    from restoration.evaluate.runner import load_runner

    from isp.runtime.executor import pool_executor

    t0 = time.perf_counter()
    settings = EvalSettings() if settings is None else settings
    if not isinstance(settings, EvalSettings):
        raise ConfigError(f"settings must be an EvalSettings, got {type(settings).__name__}")
    ex = pool_executor(None, progress=True) if executor is None else executor
    seed, baseline = settings.seed, settings.baseline
    runner = (load_runner(model, threads=threads, device=device) if isinstance(model, (str, os.PathLike))
              else model)
    t_load = time.perf_counter() - t0
    synth = _with_model_process(synth, getattr(runner, "meta", {}) or {})
    given = {"noise": None if settings.noise is None else bool(settings.noise), "exposure_ev": settings.exposure_ev,
             "noise_scale": settings.noise_scale}
    given = {k: v for k, v in given.items() if v is not None}
    if given:
        from dataclasses import replace

        synth = replace(synth or SynthSettings(), **given)
    plan = eval_plan(lens, images_dir, settings=settings, synth=synth, cameras=cameras, psf_options=psf_options,
                     cache_dir=cache_dir, executor=ex)
    t_plan = time.perf_counter() - t0 - t_load
    meta = dict(getattr(runner, "meta", {}) or {})
    trained = _training_keys(getattr(runner, "info", meta))
    eval_keys = {li["psf_map_key"] for li in plan.info["lens"]["lenses"]
                 if not li["proxy"] and li.get("psf_map_key")}
    seen = sorted(eval_keys & trained)
    if seen:
        warnings.warn(f"{len(seen)} evaluation lens(es) were in the model's training set: {seen}", stacklevel=2)
    model_lens = meta.get("lens")
    # a model corrects blur in pixels: trained at another pitch than the test's, it expects another blur
    # (a proxy fitted to a 2.8 µm capture made pairs 2.1 dB milder than its 1 µm device; isp train --pixel-um)
    pitch = float(((plan.info.get("psf_map") or {}).get("sensor") or {}).get("pixel_pitch_um", 0.0))
    other = sorted(p for p in training_pitches(getattr(runner, "info", meta)) if abs(p - pitch) > 0.01 * pitch)
    if pitch and other:
        warnings.warn(f"the model was trained on pairs at {', '.join(f'{p:g}' for p in other)} µm pixels, these "
                      f"lenses' sensor has {pitch:g} µm pixels (isp train --pixel-um {pitch:g})", stacklevel=2)
    res = evaluate_plan(plan, runner, settings, executor=ex)
    res["timing"] = {"load_model": t_load, "psf_maps": t_plan, **res["timing"],
                     "wall": time.perf_counter() - t0}
    return {
        "schema": SCHEMA,
        "model": {"path": str(model) if isinstance(model, (str, os.PathLike)) else None,
                  "kind": getattr(runner, "kind", type(runner).__name__),
                  **{k: v for k, v in meta.items() if isinstance(v, (str, int, float, bool)) or v is None}},
        "images": {"dir": str(images_dir), "files": [os.path.relpath(p, images_dir) for p in plan.latents],
                   "skipped": plan.info.get("skipped_images", [])},
        "lens": {**plan.info["lens"], "model_lens": model_lens,
                 "disjoint_from_training": (not seen) if trained else None},
        **({"device": {"lens": device.lens, "basis": device.basis, "grid": list(device.grid),
                       "components": device.components, "source": device.source}} if device is not None else {}),
        "settings": {**{k: v for k, v in asdict(settings).items() if k in _SCORING}, "seed": int(seed),
                     "synth": asdict(plan.settings), "psf_map": plan.info.get("psf_map"),
                     "noise_profile": list(plan.noise_profile), "full_size": list(plan.full_size),
                     "cameras": [c.path for c in plan.cameras],
                     "ring_radius": "distance from the frame centre / half-diagonal",
                     "ssim": dict(SSIM, win_size=11), "psnr_cap_db": 100.0,
                     "baseline_rule": _baseline_rule(baseline)},
        **res,
    }


def _with_model_process(synth: SynthSettings | None, meta: dict) -> SynthSettings | None:
    """The synthesis settings with the luminance stage's tone curve and
    white point the model was trained with (metadata ``process``: a dict
    or its JSON), when the caller gave none; a warning when the caller's
    differ."""
    import json

    proc = meta.get("process")
    if isinstance(proc, str):
        try:
            proc = json.loads(proc)
        except ValueError:
            proc = None
    if not isinstance(proc, dict) or "tone" not in proc:
        return synth
    tone, white = str(proc["tone"]), float(proc.get("white", 4.0))
    if synth is None:
        return SynthSettings(tone=tone, white=white)
    if (synth.tone, synth.white) != (tone, white):
        warnings.warn(f"the model was trained with tone={tone!r}, white={white:g}; evaluating with "
                      f"tone={synth.tone!r}, white={synth.white:g}", stacklevel=3)
    return synth


def _baseline_rule(method: str) -> str:
    from restoration.evaluate.baseline import BALANCE_FLOOR, BALANCE_RANGE, RL_ITERATIONS

    if method == "wiener":
        lo, hi = BALANCE_RANGE
        return ("skimage.restoration.wiener per PSF-map region, blended by the blur's weights; one balance per "
                "crop = max over channels of (noise variance / Laplacian prior variance) + "
                f"{BALANCE_FLOOR:g}, clipped to [{lo:g}, {hi:g}] (restoration.evaluate.baseline)")
    if method == "rl":
        return f"skimage.restoration.richardson_lucy per PSF-map region, {RL_ITERATIONS} iterations"
    return "none"
