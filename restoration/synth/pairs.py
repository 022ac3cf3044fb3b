"""Training pairs for the correction slot from latent sRGB images through a
proxy camera (paper, section 4.1, "Data Preparation").

One pair, in the order light and the pipeline meet it::

    latent sRGB crop L  (the target)
      │ inverse gamma, inverse CCM, inverse luminance      synth_colour
      │   (real phone colour metadata, scene white drawn;
      │    luminosity compression 2^−EV)
      ▼ × camera neutral n                                  (unbalanced camera RGB)
      │ spatially varying blur, PSF map of the proxy        synth_optics
      │   camera (single sample) or of a lens drawn within
      │   tolerance (multiple samples), at the crop's place
      ▼
      │ Bayer sampling, Poisson–Gaussian noise              synth_sensor
      │   (NoiseProfile), quantisation
      ▼
      │ the pipeline's black level, white balance (1/n),    synth_sensor
      │   demosaic
      ▼
    input J  (camera_rgb: what the pipeline hands to the correction slot)

and ``Process(J) = gamma(ccm(luminance(J)))`` — the stages after the slot,
:func:`restoration.synth.colour.process_after_slot` — gives back ``L`` up to
blur, noise and demosaicing (tested with an ideal lens and no noise). The
loss of the paper (eq. 24) is ``‖Process(Model(J)) − L‖²``.

Every crop is ``size × size`` pixels placed at a random position of the
full sensor frame: its PSFs are those of that position, and its field
coordinates (``modules.correction.field_coordinates``) follow from the
stored origin. The latent content is independent of that position (a
random crop of a random latent image, randomly rotated by multiples of 90°
and flipped, before any optics).

Determinism: pair ``i`` draws everything from
``SeedSequence(seed, spawn_key=(1, i))`` and the lens draws from
``spawn_key=(0,)``, so a pair's bytes depend on (seed, i, inputs) only —
not on the number of workers or the shard size.

Speed (``benchmarks/synth.py``, e9 proxy, single sample, PSF map cached,
2 worker processes on a 2-core machine shared with other jobs, load
average 6–8): 1,000 pairs of 256 × 256 in 156 s (target ≤ 300 s), about
590 MB of shards. Per pair ≈ 0.1–0.3 s of one core, half of it the blur
(:class:`restoration.synth.optics.CropBlur`).
"""

from __future__ import annotations

import math
import os
import time
import weakref
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from isp.errors import ConfigError, InputError
from isp.runtime.executor import worker_payload

from restoration.synth.colour import (
    CameraProfile,
    ColourTable,
    colour_table,
    draw_colour,
    srgb_to_camera,
)
from restoration.synth.optics import CropBlur, map_margin_px, window_reach_px
from restoration.synth.optics import psf_options as _psf_options
from restoration.synth.sensor import (
    DEFAULT_NOISE_PROFILE,
    capture_mosaic,
    develop,
    noise_profile_of,
    sensor_model,
)
from restoration.synth.shards import (
    SCHEMA,
    data_sha256,
    file_sha256,
    shard_name,
    write_manifest,
    write_shard,
)

__all__ = ["SynthPlan", "SynthSettings", "crop_blur", "find_latents", "generate", "make_pair", "plan", "read_latent",
           "seeded_rng", "sensor_geometry"]

#: image suffixes read as latent images
LATENT_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")

BLENDS = ("bilinear", "nearest")
#: ``SynthSettings.positions``: where crops are placed on the frame
POSITIONS = ("frame", "radius")


def _pair_range(v, name: str, lo: float = -math.inf, hi: float = math.inf) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in v)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be two numbers (low, high), got {v!r}") from None
    if not (math.isfinite(a) and math.isfinite(b) and lo <= a <= b <= hi):
        raise ConfigError(f"{name} must satisfy {lo:g} <= low <= high <= {hi:g}, got ({a:g}, {b:g})")
    return a, b


@dataclass(frozen=True)
class SynthSettings:
    """What a pair looks like (everything but the inputs and the seed).

    Parameters
    ----------
    size : int
        Crop side in pixels (even, ≥ 16).
    exposure_ev : (low, high)
        Luminosity compression, EV (uniform).
    cct_k : (low, high)
        Scene white, kelvin, 1667–25000.
    cct_steps : int
        Scene whites drawn from, equally spaced in mired over ``cct_k``.
    noise_scale : (low, high)
        ISO-like factor on the NoiseProfile (log-uniform).
    noise, quantise : bool
        Sensor noise; quantisation to the camera's levels (and saturation).
    blend : {"bilinear", "nearest"}
        PSF interpolation between region centres, or one PSF per region.
    demosaic : str
        The pipeline's demosaic method.
    tone : {"none", "reinhard", "aces"}
        The luminance stage's tone curve (``white`` its white point).
    augment : bool
        Random rot90/flip of the latent crop.
    positions : {"frame", "radius"}
        Where a crop lies on the frame (:func:`crop_origin`): "frame"
        (default), uniformly over the frame, so that each field ring gets
        pairs in proportion to its area (on e9's sensor 6–7 % of the centres
        lie in an evaluation's outer ring, ``r ≥ 0.8`` of the
        half-diagonal, under 1 % beyond 0.9); "radius", its centre at a radius
        uniform up to the corner crop's, so that a ring's share is its
        width (the outer ring, where the lenses of a design differ most,
        about 16 %; 5 % beyond 0.9).
    """

    size: int = 256
    exposure_ev: tuple[float, float] = (0.0, 2.0)
    cct_k: tuple[float, float] = (2850.0, 7500.0)
    cct_steps: int = 32
    noise_scale: tuple[float, float] = (0.5, 2.0)
    noise: bool = True
    quantise: bool = True
    blend: str = "bilinear"
    demosaic: str = "malvar2004"
    tone: str = "none"
    white: float = 4.0
    augment: bool = True
    positions: str = "frame"

    def __post_init__(self):
        from modules.demosaic import METHODS
        from modules.luminance import TONE_CURVES

        if not (isinstance(self.size, (int, np.integer)) and self.size >= 16 and self.size % 2 == 0):
            raise ConfigError(f"size must be an even integer ≥ 16, got {self.size!r}")
        object.__setattr__(self, "exposure_ev", _pair_range(self.exposure_ev, "exposure_ev", -8, 16))
        object.__setattr__(self, "cct_k", _pair_range(self.cct_k, "cct_k", 1667, 25000))
        object.__setattr__(self, "noise_scale", _pair_range(self.noise_scale, "noise_scale", 1e-6, 1e6))
        if not (isinstance(self.cct_steps, (int, np.integer)) and 1 <= self.cct_steps <= 4096):
            raise ConfigError(f"cct_steps must be an integer 1..4096, got {self.cct_steps!r}")
        if self.blend not in BLENDS:
            raise ConfigError(f"unknown blend {self.blend!r}; valid: {', '.join(BLENDS)}")
        if self.positions not in POSITIONS:
            raise ConfigError(f"unknown positions {self.positions!r}; valid: {', '.join(POSITIONS)}")
        if self.demosaic not in METHODS:
            raise ConfigError(f"unknown demosaic method {self.demosaic!r}; valid: {', '.join(METHODS)}")
        if self.tone not in TONE_CURVES:
            raise ConfigError(f"unknown tone curve {self.tone!r}; valid: {', '.join(TONE_CURVES)}")
        if not self.white > 0:
            raise ConfigError(f"white must be positive, got {self.white!r}")


def crop_origin(full_size, size: int, rng: np.random.Generator, positions: str = "frame") -> tuple[int, int]:
    """Top-left pixel ``(row, col)`` of a ``size × size`` crop on a
    ``full_size = (H, W)`` frame (``SynthSettings.positions``).

    "frame": uniform over the origins that keep the crop inside. "radius":
    the crop's centre at a field radius ``ρ`` (over the half-diagonal)
    uniform from 0 to the corner crop's, at an angle drawn among the 360
    (random phase) whose centre keeps the crop inside the frame.

    >>> rng = np.random.default_rng(0)
    >>> o = np.array([crop_origin((3000, 4000), 256, rng, "radius") for _ in range(2000)])
    >>> bool(o.min() >= 0 and (o[:, 0] <= 3000 - 256).all() and (o[:, 1] <= 4000 - 256).all())
    True
    >>> r = np.hypot(o[:, 0] + 128 - 1500, o[:, 1] + 128 - 2000) / 2500
    >>> round(float(np.mean(r >= 0.8)), 2), round(float(r.max()), 3)
    (0.13, 0.928)
    """
    fh, fw = (int(v) for v in full_size)
    if positions == "frame":
        return int(rng.integers(fh - size + 1)), int(rng.integers(fw - size + 1))
    hy, hx = (fh - size) / 2.0, (fw - size) / 2.0          # the centre's reach from the frame's centre
    reach = rng.uniform(0.0, math.hypot(hy, hx))
    theta = rng.uniform(0.0, 2.0 * math.pi) + np.arange(360) * (2.0 * math.pi / 360)
    dy, dx = reach * np.sin(theta), reach * np.cos(theta)
    inside = np.flatnonzero((np.abs(dy) <= hy) & (np.abs(dx) <= hx))
    k = int(inside[rng.integers(len(inside))]) if len(inside) else int(np.argmin(np.abs(np.abs(dy) - hy)
                                                                                   + np.abs(np.abs(dx) - hx)))
    row = min(max(round(hy + dy[k]), 0), fh - size)
    col = min(max(round(hx + dx[k]), 0), fw - size)
    return row, col


@dataclass(frozen=True, eq=False)
class SynthPlan:
    """Everything a pair is made from: picklable, shipped once to each worker.

    Attributes
    ----------
    maps : tuple of PSFMap or None
        One per lens (None: an ideal lens, no blur).
    cameras : tuple of CameraProfile
        Colour models drawn from; the first is also the sensor (CFA,
        levels, NoiseProfile).
    colours : ColourTable
        Their neutrals and matrices at the scene whites
        (:func:`restoration.synth.colour.colour_table`).
    latents : tuple of str
        Latent sRGB image files.
    full_size : (H, W)
        The full frame (sensor) the crops are placed on.
    seed : int
    settings : SynthSettings
    noise_profile : (S, O)
        The sensor camera's NoiseProfile before scaling.
    info : dict
        JSON-ready provenance (lenses, PSF settings) for the manifest.
    """

    maps: tuple
    cameras: tuple[CameraProfile, ...]
    colours: ColourTable
    latents: tuple[str, ...]
    full_size: tuple[int, int]
    seed: int = 0
    settings: SynthSettings = field(default_factory=SynthSettings)
    noise_profile: tuple[float, float] = DEFAULT_NOISE_PROFILE
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if not self.maps:
            raise ConfigError("no lens: give at least one PSF map (or None for an ideal lens)")
        if not self.cameras:
            raise ConfigError("no camera metadata: give at least one DNG with colour tags")
        if self.cameras[0].meta.cfa is None:
            raise ConfigError(f"{self.cameras[0].path}: the first camera is the sensor and must be a Bayer "
                              "DNG (this one is linear); list a Bayer DNG first")
        if not self.latents:
            raise ConfigError("no latent images")
        h, w = (int(v) for v in self.full_size)
        if h < self.settings.size or w < self.settings.size:
            raise ConfigError(f"crops of {self.settings.size} px do not fit the {h}×{w} frame")
        object.__setattr__(self, "full_size", (h, w))
        geo = {(m.sensor.height_px, m.sensor.width_px) for m in self.maps if m is not None}
        if geo and geo != {(h, w)}:
            raise ConfigError(f"the PSF maps' sensors {sorted(geo)} differ from the frame {(h, w)}")

    @property
    def margin(self) -> int:
        """Context pixels around each crop (blur reach + demosaic)."""
        return max([map_margin_px(m) for m in self.maps] + [0]) + 4

    @property
    def cfa(self):
        return self.cameras[0].meta.cfa


# -- latent images ------------------------------------------------------------------------

def find_latents(directory) -> list[Path]:
    """Latent image files under ``directory`` (recursively, sorted).

    Raises
    ------
    InputError
        Not a folder, or no image in it.
    """
    d = Path(directory)
    if not d.is_dir():
        raise InputError(d, "latent image folder not found")
    files = sorted(p for p in d.rglob("*") if p.suffix.lower() in LATENT_SUFFIXES and p.is_file())
    if not files:
        raise InputError(d, f"no latent images ({', '.join(LATENT_SUFFIXES)}) in this folder")
    return files


def usable_latents(files, work: int, where=None) -> list[Path]:
    """The latent images at least ``work`` pixels on each side (sizes read
    from the file headers).

    Raises
    ------
    InputError
        None is large enough (the message says the largest found).
    """
    from PIL import Image

    keep, largest = [], (0, 0, 0)
    for f in files:
        try:
            with Image.open(f) as im:
                w, h = im.size
        except OSError as e:
            raise InputError(f, f"cannot read this latent image: {e}") from None
        largest = max(largest, (min(h, w), h, w))
        if h >= work and w >= work:
            keep.append(Path(f))
    if not keep:
        raise InputError(where or Path(files[0]).parent,
                         f"no latent image is {work}×{work} or larger (a crop with its context; largest found "
                         f"{largest[1]}×{largest[2]}); use larger images or a smaller --size")
    return keep


@lru_cache(maxsize=64)
def read_latent(path: str) -> np.ndarray:
    """(H, W, 3) uint8 or uint16 RGB of an image file (alpha dropped, grey expanded)."""
    import cv2

    img = cv2.imread(path, cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    if img is None:
        raise InputError(path, "cannot read this latent image")
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(path, f"latent images must be 8- or 16-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = np.ascontiguousarray(img[:, :, 2::-1])   # BGR(A) → RGB
    img.setflags(write=False)
    return img


# -- one pair ----------------------------------------------------------------------------

def seeded_rng(seed: int, *key: int) -> np.random.Generator:
    """The generator of stream ``key`` under ``seed``
    (``SeedSequence(seed, spawn_key=key)``): each draw of a pair (lenses,
    colour, place, noise) has its own stream, so changing one leaves the
    others as they were."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key)))


def make_pair(plan: SynthPlan, index: int) -> dict:
    """Synthesise pair ``index`` of a plan (deterministic).

    Returns
    -------
    dict
        ``input`` (size, size, 3) float32 camera RGB after demosaic,
        ``target`` (size, size, 3) uint8/uint16 latent sRGB, and the
        per-pair metadata of :data:`restoration.synth.shards.SHARD_KEYS`.
    """
    st = plan.settings
    rng = seeded_rng(plan.seed, 1, index)
    k_lens = index % len(plan.maps)
    psfmap = plan.maps[k_lens]
    colour = draw_colour(plan.colours, rng, exposure_ev=st.exposure_ev)
    lo, hi = st.noise_scale
    k_noise = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
    s0, o0 = plan.noise_profile
    profile = (k_noise * s0, k_noise * k_noise * o0)

    m, n = plan.margin, st.size
    work = n + 2 * m
    li = int(rng.integers(len(plan.latents)))
    latent = read_latent(plan.latents[li])
    lh, lw = latent.shape[:2]
    if lh < work or lw < work:
        raise InputError(plan.latents[li], f"latent image {lh}×{lw} is smaller than a crop with its context "
                                           f"({work}×{work}); use larger images or a smaller --size")
    r, c = int(rng.integers(lh - work + 1)), int(rng.integers(lw - work + 1))
    rot, flip = (int(rng.integers(4)), int(rng.integers(2))) if st.augment else (0, 0)
    crop = latent[r:r + work, c:c + work]
    crop = np.rot90(crop, rot)
    if flip:
        crop = crop[:, ::-1]
    crop = np.ascontiguousarray(crop)
    origin = crop_origin(plan.full_size, n, rng, st.positions)
    work_origin = (origin[0] - m, origin[1] - m)

    srgb = crop.astype(np.float32) * np.float32(1.0 / np.iinfo(crop.dtype).max)
    cam = srgb_to_camera(srgb, colour, tone=st.tone, white=st.white)
    cam *= colour.neutral.astype(np.float32)                    # unbalanced: what the sensor sees
    blurred = cam if psfmap is None else crop_blur(plan, k_lens)(cam, work_origin)
    sensor = sensor_model(plan.cameras[0].meta, sensor_geometry(plan), profile)
    mos = capture_mosaic(blurred, sensor, work_origin, rng, noise=st.noise, quantise=st.quantise)
    rgb = develop(mos, sensor.cfa.shifted(*work_origin), colour.neutral, st.demosaic)
    return {
        "input": rgb[m:m + n, m:m + n], "target": crop[m:m + n, m:m + n], "index": int(index),
        "origin": np.array(origin, np.int32), "lens": k_lens, "camera": colour.camera, "cct": colour.cct,
        "neutral": colour.neutral, "ccm": colour.ccm, "exposure_ev": colour.exposure_ev,
        "luma_weights": colour.luma_weights, "noise_profile": np.array(profile, np.float64),
        "latent": li, "latent_box": np.array([r + m, c + m, rot, flip], np.int32),
    }


_BLURS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def crop_blur(plan: SynthPlan, k: int) -> CropBlur:
    """The plan's :class:`CropBlur` of lens ``k`` (built once per process)."""
    per = _BLURS.setdefault(plan, {})
    if k not in per:
        per[k] = CropBlur(plan.maps[k], plan.settings.blend)
    return per[k]


def sensor_geometry(plan: SynthPlan):
    """The :class:`calibration.optics.lens.Sensor` the plan's PSF maps were
    made for (size and pitch of the full frame); 1 µm pixels over
    ``plan.full_size`` where the plan has no map."""
    from calibration.optics.lens import Sensor

    for mp in plan.maps:
        if mp is not None:
            return mp.sensor
    h, w = plan.full_size
    return Sensor(pixel_pitch_um=1.0, width_px=w, height_px=h)


# -- building a plan -----------------------------------------------------------------------

def plan(lens, *, samples: int = 1, latent_dir, cameras, seed: int = 0, settings: SynthSettings | None = None,
         tolerance_scale: float = 1.0, psf_options: dict | None = None, cache_dir=None,
         pixel_um: float | None = None, executor=None, basis=None, device_components: int = 16) -> SynthPlan:
    """Read the inputs and compute (or read from the cache) the PSF maps.

    Parameters
    ----------
    lens : path or PerturbedLens
        The proxy camera's lens (lens file or fitted proxy file).
    samples : int
        1: the proxy lens alone; N: the proxy and N − 1 lenses drawn
        within ``tolerance_scale`` × the default tolerances.
    latent_dir : path
        Folder of latent sRGB images (searched recursively).
    cameras : sequence of path
        Phone DNGs whose colour tags are drawn from; the first is also the
        sensor (Bayer CFA, levels, NoiseProfile).
    seed : int
    settings : SynthSettings, optional
    psf_options : dict, optional
        :class:`calibration.optics.psf.map.PSFMapSettings` fields (grid, n, ...).
    cache_dir : path, optional
        PSF-map cache (default ``$ISP_CACHE/psf`` or ``~/.cache/phone-isp/psf``).
    pixel_um : float, optional
        The pairs' pixel pitch, µm: the lens file's sensor area sampled at
        this pitch (:meth:`calibration.optics.lens.Sensor.at_pitch`). A proxy
        fitted to a binned capture carries that capture's sensor; the pairs
        must be made at the pitch the correction will run on.
    executor : isp.runtime.executor.Executor, optional
        Runs the PSF maps' regions (default psf_map's: up to 2 worker
        processes, with progress bars).
    basis : path, optional
        The design's descriptor basis (``isp calib basis``): each lens's
        ``device/v1`` descriptor is computed on it and written to the
        manifest (``device``), so that a network conditioned on the device
        learns from pairs that carry their lens's descriptor
        (:class:`restoration.train.trainer.PairBank`).
    device_components : int
        Descriptor components kept (≤ the basis's).
    """
    from calibration.optics.perturb import apply

    from restoration.synth.colour import read_camera
    from restoration.synth.optics import draw_lenses, load_lens, psf_maps

    settings = settings or SynthSettings()
    lens_path = None
    if isinstance(lens, (str, os.PathLike)):
        lens_path = str(lens)
        lens = load_lens(lens)
    if pixel_um:
        nom = lens.nominal
        lens = apply(nom.replace(sensor=nom.sensor.at_pitch(pixel_um)), lens.perturbation)
    opts = _psf_options(psf_options)
    # context of a crop, before the maps exist: the PSF window's reach (+ demosaic)
    reach = window_reach_px(opts["n"], opts.get("pitch_um"), lens.nominal.sensor.pixel_pitch_um)
    latents = usable_latents(find_latents(latent_dir), settings.size + 2 * (reach + 4), latent_dir)
    cams = tuple(read_camera(p) for p in cameras)
    if not cams:
        raise ConfigError("no camera metadata: give at least one DNG with colour tags")
    lenses = draw_lenses(lens, int(samples), seeded_rng(seed, 0), tolerance_scale=tolerance_scale)
    maps = tuple(psf_maps(lenses, executor=executor, cache_dir=cache_dir, **opts))
    sensor = maps[0].sensor
    prof = noise_profile_of(cams[0].meta)
    info = {
        "lens": {"path": lens_path, "name": lens.nominal.name, "samples": int(samples),
                 "tolerance_scale": float(tolerance_scale),
                 "lenses": [{"perturbation": {k: v for k, v in sorted(pl.perturbation.as_dict().items()) if v},
                             "psf_map_key": mp.key} for pl, mp in zip(lenses, maps)]},
        "psf_map": maps[0].settings,
        "noise_profile_source": "file" if prof else "default (the sensor camera has no NoiseProfile)",
    }
    if basis is not None:
        info["device"] = lens_descriptors(lenses, basis, device_components, executor=executor, cache_dir=cache_dir)
    colours = colour_table(list(cams), settings.cct_k, settings.cct_steps)
    return SynthPlan(maps, cams, colours, tuple(str(p) for p in latents), (sensor.height_px, sensor.width_px), int(seed),
                     settings, prof or DEFAULT_NOISE_PROFILE, info)


def lens_descriptors(lenses, basis, components: int = 16, *, executor=None, cache_dir=None) -> dict:
    """The ``device/v1`` descriptor of each lens on a basis file, as the
    manifest's ``device`` entry: the basis's lens, design and key, the grid,
    ``components`` and one ``rows × cols × K`` list per lens (4 significant
    digits, as a device file holds them)."""
    from calibration.fit.device import describe, load_basis
    from isp.io.device import rounded

    b = load_basis(basis, lenses[0])
    k = min(int(components), b.size)
    return {"lens": b.lens, "design": b.design, "basis": b.key, "basis_file": str(basis), "grid": list(b.grid),
            "components": k,
            "descriptors": [rounded(describe(pl, b, k, executor=executor, cache_dir=cache_dir)) for pl in lenses]}


# -- many pairs ----------------------------------------------------------------------------

def _setup_worker(p: SynthPlan) -> SynthPlan:
    """A synthesis worker's setup (once per worker; in this process for a
    serial executor): OpenCV and BLAS on one thread, one process per core;
    the plan is its payload."""
    import cv2

    from isp.runtime.threads import one_blas_thread

    cv2.setNumThreads(1)        # one process per core: no nested threads
    one_blas_thread()
    return p


def _target_dtype(p: SynthPlan):
    return np.uint16 if any(read_latent(f).dtype == np.uint16 for f in p.latents) else np.uint8


def _input_for_shard(pair: dict) -> dict:
    pair = dict(pair)
    pair["input"] = pair["input"].astype(np.float16)
    return pair


def _shard_task(job: tuple) -> dict:
    """One shard, made and written by the worker: pairs ``first`` to
    ``first + count - 1`` of the plan (the payload) into ``path``
    (atomically: a retried or interrupted task leaves the whole shard or
    none). The pairs depend on the seed and their indices alone, so the
    file is the same whichever worker writes it."""
    path, first, count, tdtype = job
    p = worker_payload()
    return write_shard(path, [_input_for_shard(make_pair(p, i)) for i in range(first, first + count)],
                       np.dtype(tdtype).type)


def generate(p: SynthPlan, out_dir, pairs: int, *, shard_size: int = 100, force: bool = False,
             executor=None) -> dict:
    """Synthesise ``pairs`` pairs into shards under ``out_dir`` and write the
    manifest.

    Each shard is one task: the worker makes its pairs and writes the file
    (:func:`_shard_task`), so only the shards' records travel back, and a
    cluster's workers write to the shared output folder directly.

    Parameters
    ----------
    p : SynthPlan
    out_dir : path
        Created if missing; must not hold a previous set unless ``force``.
        On a cluster, a folder every node writes to (a shared file system).
    pairs : int
    shard_size : int
        Pairs per shard file (the unit of work: at least as many shards as
        workers keeps every worker busy).
    force : bool
        Replace a previous set in ``out_dir``.
    executor : isp.runtime.executor.Executor, optional
        Runs the shards, independent tasks, the plan each worker's payload
        (default: 2 worker processes with a progress bar; "serial": in this
        process). The files are the same on any executor (tested).

    Returns
    -------
    dict
        The manifest (also written to ``out_dir/manifest.json``).
    """
    from isp.runtime.executor import pool_executor

    if int(pairs) < 1 or int(shard_size) < 1:
        raise ConfigError(f"pairs and shard_size must be ≥ 1, got {pairs}, {shard_size}")
    ex = pool_executor(2, progress=True) if executor is None else executor
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(out, "output exists and is not a folder")
    old = sorted(out.glob("shard-*.npz")) + ([out / "manifest.json"] if (out / "manifest.json").exists() else [])
    if old and not force:
        raise InputError(out, f"holds a previous set ({len(old)} files); choose another folder or use --force")
    out.mkdir(parents=True, exist_ok=True)
    for f in old:
        f.unlink()
    tdtype = np.dtype(_target_dtype(p)).name
    n, size = int(pairs), int(shard_size)
    jobs = [(str(out.resolve() / shard_name(k)), first, min(size, n - first), tdtype)
            for k, first in enumerate(range(0, n, size))]
    t0 = time.perf_counter()
    shards = []
    with ex.bar(total=n, desc="synth", unit="pair", smoothing=0.1) as bar, \
            ex.bind(p, setup=_setup_worker) as job:
        for record, (_, _, count, _) in zip(job.imap(_shard_task, jobs, chunksize=1), jobs):
            shards.append(record)
            bar.update(count)
    seconds = time.perf_counter() - t0
    manifest = _manifest(p, n, size, shards, np.dtype(tdtype).type)
    write_manifest(out, manifest)
    manifest["_seconds"] = seconds            # not written: the file stays deterministic
    return manifest


def _manifest(p: SynthPlan, pairs: int, shard_size: int, shards: list[dict], tdtype) -> dict:
    from isp.pipeline import LOOKS

    stages = LOOKS["linear"]    # the look the correction is trained and evaluated on
    root = Path(os.path.commonpath(p.latents)) if len(p.latents) > 1 else Path(p.latents[0]).parent
    cam0 = p.cameras[0].meta
    slot = stages.index("correction")
    return {
        "schema": SCHEMA,
        "seed": p.seed,
        "pairs": pairs,
        "size": p.settings.size,
        "shard_size": shard_size,
        "settings": asdict(p.settings),
        "domain": "camera_rgb",
        "placement": f"after {stages[slot - 1]}, before {stages[slot + 1]}",
        "process": {"stages": ["luminance", "ccm", "gamma"],
                    "luminance": {"tone": p.settings.tone, "white": p.settings.white,
                                  "gain": "2**exposure_ev per pair"},
                    "ccm": "per-pair matrix 'ccm' (balanced camera RGB -> linear sRGB)",
                    "gamma": "srgb"},
        "full_size": list(p.full_size),
        "cfa": cam0.cfa.value,
        "field_coordinates": "modules.correction.field_coordinates((size, size), origin, full_size)",
        "noise_profile": list(p.noise_profile),
        "cameras": [{"path": c.path, "name": c.name, "sha256": file_sha256(c.path)} for c in p.cameras],
        "latent": {"root": str(root),
                   "files": [{"path": os.path.relpath(f, root), "sha256": file_sha256(f)} for f in p.latents]},
        "target_max": int(np.iinfo(tdtype).max),
        **p.info,
        "shards": shards,
        "data_sha256": data_sha256(shards),
    }
