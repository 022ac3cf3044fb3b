"""PSF maps: one polychromatic PSF per sensor region and colour channel.

The paper divides the sensor into 15 × 20 regions and blurs each with the
PSF of its centre (section 3.1.2 and 4.1). :func:`psf_map` computes them for
a (perturbed) lens: region centres on the sensor → object fields by
inverting the real chief ray → per-wavelength PSFs (:mod:`calibration.optics.psf`)
→ weighted per channel (eq. 14), with an on-disk cache.

Sensor coordinates
------------------
Pixel ``(x_px, y_px)``: origin at the top-left pixel, +x to the right
(increasing column), +y down (increasing row), pixel centres at integer
coordinates (pixel ``(0, 0)`` covers ``[−0.5, 0.5]²``). The optical axis
meets the sensor at its centre, and the map to the image plane is a pure
shift and scale, with **no flip**:

.. math::

    x_\\mathrm{mm} = \\left(x_\\mathrm{px} - \\tfrac{W-1}{2}\\right) p,\\qquad
    y_\\mathrm{mm} = \\left(y_\\mathrm{px} - \\tfrac{H-1}{2}\\right) p

(``W × H`` pixels of pitch ``p`` mm; :func:`sensor_to_image`,
:func:`image_to_sensor`). So image-plane +y points *down* the sensor array
(toward larger rows) and +x to the right: the frame is the image plane seen
along the light (looking along +z from the lens), x right, y down — a
right-handed frame with z into the page. Consequences:

* A PSF's ``data[i, j]`` (rows along image-plane +y, columns along +x, see
  :mod:`calibration.optics.psf`) is directly a convolution kernel on the sensor
  array (rows = y_px): no flip, no transpose. Its centre sample
  ``data[n//2, n//2]`` sits on the region centre.
* A chief ray at a positive field θy (travelling toward +y) lands at
  positive image-plane y, i.e. in the *lower* half of the array.
* An upright photograph of the scene (what a camera's readout shows after
  its orientation flag) is this array mirrored left–right (the lens inverts
  the image; seen from the lens the inversion is a 180° rotation, read out
  upright it is a mirror in x). For a rotationally symmetric nominal lens the
  mirror is immaterial; for a fitted perturbation it mirrors decenters in x.

Regions: ``grid = (rows, cols)`` splits the sensor into equal rectangles;
region ``(r, c)`` covers ``x_px ∈ [c·W/cols − ½, (c+1)·W/cols − ½)`` and
``y_px ∈ [r·H/rows − ½, (r+1)·H/rows − ½)``; its centre (``centers_mm``) is
where the PSF is computed and the real chief ray (real aiming, primary
wavelength) lands. PSFs are centred on that point for every channel, so
lateral colour is kept (a channel's PSF is offset), distortion is not (it
is in ``field_deg``).

Symmetry: a *coaxial* lens — the nominal one, or one perturbed only in
curvatures, conics, aspheric terms, thicknesses and materials (every pose
an identity rotation on the axis) — is symmetric about the x–z and y–z
planes, and the region grid is built symmetric about the axis, so the PSF
of region ``(rows−1−r, c)`` is that of ``(r, c)`` mirrored in y (and
likewise in x). ``symmetry="auto"`` then computes one quadrant (regions
with ``x, y ≥ 0``: 80 of 300) on an odd-sized grid and mirrors it; the
result equals the full computation to ~1e-12 of the peak (the real
aiming's forward differences are not mirror-symmetric; tested). Lenses
with a decenter or tilt are computed in full.

Cache: ``<cache_dir>/<key>.npz``, ``key`` = SHA-256 of the perturbed lens's
geometry (nominal prescription, perturbation, and the resulting surfaces
and poses, floats in exact hex) and every setting that changes the result;
written atomically (temporary file, fsync, rename). ``cache_dir`` defaults
to ``$ISP_CACHE/psf``, else ``~/.cache/phone-isp/psf``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from isp.errors import ConfigError
from isp.runtime.executor import Executor, pool_executor, worker_payload

from calibration.optics import paraxial
from calibration.optics.lens import Lens, Sensor
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.optics.psf.methods import METHODS, monochromatic_samples
from calibration.optics.psf.pupil import exit_pupil_z, reference_sphere, trace_pupils
from calibration.optics.psf.result import PSF, PSFError
from calibration.optics.psf.sampling import grid_offsets_mm
from calibration.optics.psf.spectral import (
    DEFAULT_CAMERA,
    DEFAULT_WAVELENGTHS_PER_CHANNEL,
    channel_quadrature,
)
from calibration.optics.trace import Rays, stop_and_pupil, trace

__all__ = [
    "CACHE_VERSION",
    "PSFMap",
    "PSFMapSettings",
    "WINDOW_UM",
    "cache_key",
    "check_window",
    "chief_ray_fields",
    "default_psf_n",
    "image_to_sensor",
    "plot_psf_map",
    "psf_map",
    "region_centers_mm",
    "sensor_to_image",
]

CACHE_VERSION = 1
"""Bumped whenever a change to the PSF code changes the numbers."""

WINDOW_UM = 32.0
"""Default side of a PSF window, µm (:func:`default_psf_n`; the fit's
``ModelSettings.window_um`` too). A lens's PSF is as wide in µm whatever
the pixel: a window of a fixed sample count shrinks with the pixel pitch.
32 samples at half a pixel would be 16 µm on 1 µm pixels, where a device
drawn within e9's tolerance keeps only 47 % of a corner PSF, and a capture
simulated through such a window (``isp calib simulate`` at the
prescription's sensor) would be sharper than its lens."""

WINDOW_ENERGY_WARN = 0.9
""":func:`psf_map` warns when a PSF keeps less than this share of its energy
inside the window (a lens blurred beyond it: e.g. e9 with element 1
decentred by its 5 µm tolerance keeps 71 % in 16 µm)."""


def default_psf_n(pitch_um: float, window_um: float = WINDOW_UM, minimum: int = 32,
                  max_um: float = 48.0) -> int:
    """Samples per side of a PSF window at least ``window_um`` µm wide at
    ``pitch_um`` µm per sample: even, and at least ``minimum`` samples
    (coarse pixels keep the 32 they always had) where those stay within
    ``max_um`` µm: the replica period of psf_map's default 64 pupil samples
    is ≈ 55 µm on e9 at 441 nm (:func:`check_window`), and 32 samples of
    4.4 µm (8.8 µm pixels) would be 140 µm.

    >>> default_psf_n(0.5), default_psf_n(1.4), default_psf_n(0.35), default_psf_n(4.39)
    (64, 32, 92, 10)
    """
    p = float(pitch_um)
    need = 2 * math.ceil(float(window_um) / (2.0 * p) - 1e-9)
    floor = min(int(minimum), 2 * int(float(max_um) / (2.0 * p)))
    return max(need, floor)


def check_window(lens, n: int, pitch_um: float, pupil_samples: int, lam_min_nm: float, *,
                 fix: str = "a smaller n") -> None:
    """Refuse a PSF window wider than the replica period of the sampled
    pupil: ``pupil_samples`` samples across a pupil of image-space
    numerical aperture 1/(2N) (N the working F-number) make the diffracted
    field periodic with period λ·N·``pupil_samples``; a window past it
    folds the far tails back onto the core, silently for the "debye" and
    "huygens" sums. ``fix`` names the other way out in the message.

    Raises
    ------
    PSFError
        Naming the window, the period and the pupil samples that would do.
    """
    n_w = paraxial.first_order(nominal(lens).lens).working_f_number
    if not (math.isfinite(n_w) and n_w > 0):
        return
    period_um = lam_min_nm * 1e-3 * n_w * pupil_samples
    window_um = n * pitch_um
    if window_um > period_um:
        need = math.ceil(window_um / (lam_min_nm * 1e-3 * n_w))
        raise PSFError(f"the PSF window ({window_um:.3g} µm: {n} samples × {pitch_um:.3g} µm) exceeds the "
                       f"pupil sampling's replica period (≈ {period_um:.3g} µm at {lam_min_nm:.0f} nm, "
                       f"N = {n_w:.2f}, {pupil_samples} samples): use pupil_samples ≥ {need} or {fix}")


# -- sensor geometry ------------------------------------------------------------------

def sensor_to_image(x_px, y_px, sensor: Sensor) -> tuple[np.ndarray, np.ndarray]:
    """Image-plane (x, y) in mm of sensor pixel coordinates (see the module
    docstring: pure shift and scale, +y down the array).

    >>> s = Sensor(pixel_pitch_um=1.0, width_px=4, height_px=2)
    >>> [float(v) for v in sensor_to_image(0, 0, s)]
    [-0.0015, -0.0005]
    """
    p = sensor.pixel_pitch_um * 1e-3
    return ((np.asarray(x_px, dtype=np.float64) - 0.5 * (sensor.width_px - 1)) * p,
            (np.asarray(y_px, dtype=np.float64) - 0.5 * (sensor.height_px - 1)) * p)


def image_to_sensor(x_mm, y_mm, sensor: Sensor) -> tuple[np.ndarray, np.ndarray]:
    """Sensor pixel coordinates of image-plane points (mm); the inverse of
    :func:`sensor_to_image`."""
    p = sensor.pixel_pitch_um * 1e-3
    return (np.asarray(x_mm, dtype=np.float64) / p + 0.5 * (sensor.width_px - 1),
            np.asarray(y_mm, dtype=np.float64) / p + 0.5 * (sensor.height_px - 1))


def region_centers_mm(sensor: Sensor, grid: tuple[int, int]) -> np.ndarray:
    """(rows, cols, 2) image-plane centres (x, y) of the regions, mm;
    exactly antisymmetric about the axis (region ``(rows−1−r, cols−1−c)``
    is the negative of ``(r, c)``)."""
    rows, cols = grid
    w, h = sensor.size_mm
    x = (2.0 * np.arange(cols) + 1.0 - cols) * (w / (2.0 * cols))
    y = (2.0 * np.arange(rows) + 1.0 - rows) * (h / (2.0 * rows))
    out = np.empty((rows, cols, 2))
    out[..., 0] = x[None, :]
    out[..., 1] = y[:, None]
    return out


# -- the map ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PSFMap:
    """Polychromatic PSFs over the sensor.

    Attributes
    ----------
    psfs : (rows, cols, channels, n, n) ndarray, float32
        Each PSF sums to 1; sample grid as :class:`calibration.optics.psf.result.PSF`
        (rows along image-plane +y = sensor +y, columns along +x), centre
        sample ``[n//2, n//2]`` on the region centre.
    pitch_um : float
        PSF sample spacing, µm.
    centers_mm : (rows, cols, 2) ndarray
        Image-plane (x, y) of the region centres, mm.
    field_deg : (rows, cols, 2) ndarray
        Object field (θx, θy), degrees, whose real chief ray (primary
        wavelength) lands on each centre.
    channels : tuple of str
        E.g. ("R", "G", "B").
    sensor : Sensor
    key : str
        The cache key (SHA-256 hex) of lens + settings.
    wavelengths_nm : tuple of float
        The wavelengths computed (shared by the channels).
    channel_weights : (channels, wavelengths) ndarray
        Each channel's quadrature weights (rows sum to 1).
    method : str
    window_energy : (rows, cols, channels) ndarray
        Fraction of each PSF's power inside its window (see
        :attr:`calibration.optics.psf.result.PSF.window_energy`).
    settings : dict
        Everything that went into the key, JSON-safe.
    """

    psfs: np.ndarray
    pitch_um: float
    centers_mm: np.ndarray
    field_deg: np.ndarray
    channels: tuple[str, ...]
    sensor: Sensor
    key: str = ""
    wavelengths_nm: tuple[float, ...] = ()
    channel_weights: np.ndarray | None = None
    method: str = ""
    window_energy: np.ndarray | None = None
    settings: dict = field(default_factory=dict)

    def __post_init__(self):
        p = np.asarray(self.psfs, dtype=np.float32)
        if p.ndim != 5 or p.shape[3] != p.shape[4]:
            raise PSFError(f"psfs must be (rows, cols, channels, n, n), got shape {p.shape}")
        rows, cols, nc = p.shape[:3]
        c = np.asarray(self.centers_mm, dtype=np.float64)
        f = np.asarray(self.field_deg, dtype=np.float64)
        if c.shape != (rows, cols, 2) or f.shape != (rows, cols, 2):
            raise PSFError(f"centers_mm and field_deg must be ({rows}, {cols}, 2), got {c.shape} and {f.shape}")
        if len(tuple(self.channels)) != nc:
            raise PSFError(f"{nc} PSF channels but channels = {tuple(self.channels)!r}")
        object.__setattr__(self, "psfs", p)
        object.__setattr__(self, "centers_mm", c)
        object.__setattr__(self, "field_deg", f)
        object.__setattr__(self, "channels", tuple(str(ch) for ch in self.channels))
        object.__setattr__(self, "wavelengths_nm", tuple(float(v) for v in self.wavelengths_nm))

    @property
    def grid(self) -> tuple[int, int]:
        """(rows, cols)."""
        return self.psfs.shape[0], self.psfs.shape[1]

    @property
    def n(self) -> int:
        return self.psfs.shape[-1]

    def region_of(self, x_px, y_px):
        """(row, col) of the region holding sensor pixel coordinates
        (scalars or arrays; clipped to the grid, so pixels outside the
        sensor get the nearest border region).

        >>> m = PSFMap(np.zeros((15, 20, 1, 3, 3)), 0.5, np.zeros((15, 20, 2)), np.zeros((15, 20, 2)),
        ...            ("G",), Sensor(1.0, 400, 300))
        >>> m.region_of(0, 0), m.region_of(399, 299), m.region_of(20, 19.4)
        ((0, 0), (14, 19), (0, 1))
        """
        rows, cols = self.grid
        x = np.asarray(x_px, dtype=np.float64)
        y = np.asarray(y_px, dtype=np.float64)
        c = np.clip(np.floor((x + 0.5) * cols / self.sensor.width_px), 0, cols - 1).astype(np.intp)
        r = np.clip(np.floor((y + 0.5) * rows / self.sensor.height_px), 0, rows - 1).astype(np.intp)
        if r.ndim == 0:
            return int(r), int(c)
        return r, c

    def region_bounds_px(self, row: int, col: int) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) pixel-coordinate bounds of a region (half-open)."""
        rows, cols = self.grid
        w, h = self.sensor.width_px, self.sensor.height_px
        return (col * w / cols - 0.5, (col + 1) * w / cols - 0.5, row * h / rows - 0.5, (row + 1) * h / rows - 0.5)

    def channel_index(self, channel: str | int) -> int:
        if isinstance(channel, (int, np.integer)):
            if not 0 <= channel < len(self.channels):
                raise PSFError(f"channel index {channel} out of range for {self.channels}")
            return int(channel)
        try:
            return self.channels.index(str(channel))
        except ValueError:
            raise PSFError(f"unknown channel {channel!r}; this map has {self.channels}") from None

    def psf(self, row: int, col: int, channel: str | int) -> PSF:
        """The PSF of one region and channel (float64 copy)."""
        ci = self.channel_index(channel)
        w = self.channel_weights[ci] if self.channel_weights is not None else ()
        we = float(self.window_energy[row, col, ci]) if self.window_energy is not None else math.nan
        return PSF(self.psfs[row, col, ci].astype(np.float64), self.pitch_um, tuple(self.centers_mm[row, col]),
                   tuple(self.field_deg[row, col]), self.wavelengths_nm if len(w) else (), tuple(w),
                   self.method, we)

    # -- files -------------------------------------------------------------------------------
    def to_npz(self, path) -> Path:
        """Write the map (atomically) as ``.npz``; returns the path."""
        meta = {"pitch_um": self.pitch_um, "channels": list(self.channels),
                "sensor": dataclasses.asdict(self.sensor), "key": self.key,
                "wavelengths_nm": list(self.wavelengths_nm), "method": self.method, "settings": self.settings}
        arrays = {"psfs": self.psfs, "centers_mm": self.centers_mm, "field_deg": self.field_deg,
                  "meta": np.array(json.dumps(meta))}
        if self.channel_weights is not None:
            arrays["channel_weights"] = np.asarray(self.channel_weights, dtype=np.float64)
        if self.window_energy is not None:
            arrays["window_energy"] = np.asarray(self.window_energy, dtype=np.float64)
        from calibration.report import write_npz

        return write_npz(path, arrays)

    @classmethod
    def from_npz(cls, path) -> PSFMap:
        """Read a map written by :meth:`to_npz`."""
        with np.load(Path(path), allow_pickle=False) as z:
            try:
                meta = json.loads(str(z["meta"]))
                return cls(z["psfs"], float(meta["pitch_um"]), z["centers_mm"], z["field_deg"],
                           tuple(meta["channels"]), Sensor(**meta["sensor"]), meta.get("key", ""),
                           tuple(meta.get("wavelengths_nm", ())),
                           z.get("channel_weights", None), meta.get("method", ""),
                           z.get("window_energy", None), meta.get("settings", {}))
            except KeyError as e:
                raise PSFError(f"{path}: not a PSF map file (missing {e})") from None


# -- chief rays ------------------------------------------------------------------------------

def _start_plane(pl: PerturbedLens, z_ep: float) -> float:
    s = pl.lens.surfaces[0]
    sd = s.semi_diameter if s.semi_diameter is not None else 10.0
    with np.errstate(invalid="ignore"):
        sag = s.sag(np.linspace(0.0, sd, 64))
    lo = float(np.nanmin(sag)) if np.any(np.isfinite(sag)) else 0.0
    return min(0.0, z_ep, lo + float(pl.poses[0].vertex[2])) - 1.0 - sd


def chief_ray_fields(lens: Lens | PerturbedLens, points_mm, wavelength_nm: float | None = None, *,
                     tol: float = 1e-9, max_iter: int = 40) -> np.ndarray:
    """Object fields whose real chief rays land on given image-plane points.

    The chief ray is the real ray through the centre of the (possibly
    decentred or tilted) stop — the ray ``pupil_rays(..., aiming="real")``
    uses. Per point a 4-D Newton iteration solves for the field tangents
    ``(tan θx, tan θy)`` and the ray's crossing of the entrance-pupil plane
    such that the ray meets the stop centre and the target, all points at
    once (forward-difference Jacobian, one trace of 5·M rays per
    iteration); it starts from the paraxial guess ``tan θ = h/h₁``
    (``h₁`` the paraxial image height at tan θ = 1), which distortion
    moves by a few per cent on phone lenses. Semi-diameters are ignored
    (a vignetted chief ray still defines the field).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    points_mm : (..., 2) array_like
        Image-plane (x, y), mm.
    wavelength_nm : float, optional
        Default: the lens's primary wavelength.
    tol : float
        Accepted miss (stop centre and target), mm.

    Returns
    -------
    (..., 2) ndarray
        (θx, θy) in degrees.
    """
    pl = nominal(lens)
    lam = float(pl.nominal.primary_nm if wavelength_nm is None else wavelength_nm)
    pts = np.asarray(points_mm, dtype=np.float64)
    shape = pts.shape
    pts = pts.reshape(-1, 2)
    m = len(pts)
    if not m:
        return np.zeros(shape)
    pp = stop_and_pupil(pl)
    h1 = paraxial.image_height(pl.lens, 45.0, lam)
    if not (math.isfinite(h1) and h1 != 0):
        raise PSFError("the lens has no finite paraxial image height (afocal?); cannot map sensor points to fields")
    z0 = _start_plane(pl, pp.z)
    finite = math.isfinite(pl.lens.object_distance)
    zo = -float(pl.lens.object_distance) if finite else 0.0
    stop = pl.stop_index
    stop_pose = pl.poses[stop]

    def residual(u):
        """(K, 4) residuals (stop x, y in the stop frame; image − target) and validity."""
        tx, ty, ex, ey = u.T
        d = np.column_stack([tx, ty, np.ones_like(tx)])
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        ep = np.column_stack([ex, ey, np.full_like(ex, pp.z)])
        if finite:
            obj = np.column_stack([np.zeros_like(tx), np.zeros_like(tx), np.full_like(tx, pp.z)]) \
                - ((pp.z - zo) / d[:, 2])[:, None] * d
            origin = obj
            dirn = ep - obj
            dirn /= np.linalg.norm(dirn, axis=1, keepdims=True)
        else:
            origin = ep - ((pp.z - z0) / d[:, 2])[:, None] * d
            dirn = d
        res = trace(pl, Rays(origin, dirn, lam), to="image", clip=False, record=True)
        s_loc = stop_pose.to_local(res.surface_positions[stop])
        tgt = np.tile(pts, (len(u) // m, 1))
        return np.column_stack([s_loc[:, :2], res.position[:, :2] - tgt]), res.valid

    u = np.column_stack([pts / h1, np.zeros((m, 2))])
    steps = np.array([1e-7, 1e-7, 1e-7, 1e-7])
    for _ in range(max_iter):
        batch = np.concatenate([u] + [u + np.eye(4)[k] * steps[k] for k in range(4)])
        f, valid = residual(batch)
        if not valid[:m].all():
            bad = np.flatnonzero(~valid[:m])[0]
            raise PSFError(f"no real chief ray reaches the image point {tuple(pts[bad])} mm "
                           "(outside the lens's field?)")
        f0 = f[:m]
        err = np.max(np.abs(f0), axis=1)
        if np.all(err < tol):
            break
        jac = np.stack([(f[(k + 1) * m:(k + 2) * m] - f0) / steps[k] for k in range(4)], axis=2)   # (m, 4, 4)
        try:
            step = np.linalg.solve(jac, f0[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            raise PSFError("chief-ray inversion: singular Jacobian (a degenerate lens?)") from None
        big = np.abs(step[:, :2]).max(axis=1) > 0.2          # damp wild steps in tan θ
        step[big] *= 0.5
        u = u - np.where((err < tol)[:, None], 0.0, step)
    else:
        raise PSFError(f"chief-ray inversion did not converge to {tol:g} mm in {max_iter} iterations "
                       f"(worst miss {float(err.max()):.3g} mm)")
    return np.degrees(np.arctan(u[:, :2])).reshape(shape)


# -- cache key -----------------------------------------------------------------------------------

def canonical(obj):
    """A JSON-safe canonical form (floats as exact hex) for hashing."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj).hex()
    if isinstance(obj, np.ndarray):
        return [canonical(v) for v in obj.tolist()]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        skip = {"metadata", "name"} if isinstance(obj, Lens) else set()
        return {"__type__": type(obj).__name__,
                **{f.name: canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.name not in skip}}
    if isinstance(obj, dict):
        return {str(k): canonical(v) for k, v in sorted(obj.items())}
    if isinstance(obj, (list, tuple)):
        return [canonical(v) for v in obj]
    raise TypeError(f"cannot canonicalise {type(obj).__name__}")


def _lens_identity(pl: PerturbedLens) -> dict:
    pert = {k: v for k, v in sorted(pl.perturbation.as_dict().items()) if v != 0.0}
    return {"nominal": canonical(pl.nominal), "perturbation": canonical(pert), "lens": canonical(pl.lens),
            "poses": [[canonical(p.rotation) if p.rotation is not None else None, canonical(p.vertex)]
                      for p in (*pl.poses, pl.image_pose)]}


def cache_key(lens: Lens | PerturbedLens, settings: dict) -> str:
    """SHA-256 (hex) of the (perturbed) lens geometry and the settings.
    A zero perturbation has the nominal lens's key; the lens's name and
    metadata (e.g. its file path) do not enter."""
    blob = json.dumps({"version": CACHE_VERSION, "lens": _lens_identity(nominal(lens)), "settings": canonical(settings)},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def _cache_dir(cache_dir) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("ISP_CACHE")
    return Path(env) / "psf" if env else Path.home() / ".cache" / "phone-isp" / "psf"


# -- computing the map ------------------------------------------------------------------------------

def _is_coaxial(pl: PerturbedLens) -> bool:
    poses = (*pl.poses, pl.image_pose)
    return all(p.rotation is None and p.vertex[0] == 0.0 and p.vertex[1] == 0.0 for p in poses)


def region_task(args, dz_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """One region: (channels, m, m) PSFs and (channels,) window energies,
    on an image surface ``dz_mm`` beyond the lens's image plane there
    (+: away from the lens). A plain picklable function of its inputs
    (DESIGN.md, scale-out)."""
    pl, fld, center, nodes, weights, method, samples, m, pitch, aiming, aim_each, threads = args
    o = grid_offsets_mm(m, pitch)
    out = np.zeros((weights.shape[0], m, m))
    energy = np.zeros(weights.shape[0])
    traced = trace_pupils(pl, (float(fld[0]), float(fld[1])), nodes, samples, aiming, exit_pupil_z(pl), aim_each)
    if dz_mm:
        traced = [dataclasses.replace(tr, z_image=tr.z_image + float(dz_mm)) for tr in traced]
    for k, tr in enumerate(traced):
        data, e = monochromatic_samples(reference_sphere(tr, np.asarray(center)), method, o, o, workers=threads)
        for c in range(weights.shape[0]):
            if weights[c, k] != 0.0:
                out[c] += weights[c, k] * data
                energy[c] += weights[c, k] * e
    return out, energy


def _image_dz(image_dz_mm, grid: tuple[int, int]) -> np.ndarray:
    """``image_dz_mm`` checked: a finite (rows, cols) array (0 for None)."""
    if image_dz_mm is None:
        return np.zeros(grid)
    dz = np.asarray(image_dz_mm, dtype=np.float64)
    if dz.shape != tuple(grid) or not np.all(np.isfinite(dz)):
        raise ConfigError(f"image_dz_mm must be a finite {grid[0]} × {grid[1]} array (one per region), "
                          f"got shape {dz.shape}")
    return dz


def _mirrored(dz: np.ndarray) -> bool:
    """Whether ``dz`` is the same in the four quadrants (the map's symmetry holds)."""
    return bool(np.array_equal(dz, dz[::-1, :]) and np.array_equal(dz, dz[:, ::-1]))


@dataclass(frozen=True)
class PSFMapSettings:
    """What a PSF map computes (:func:`psf_map`): every field changes the
    numbers and enters the cache key. Checked at construction
    (:class:`isp.errors.ConfigError` naming the field and value).

    Parameters
    ----------
    grid : (rows, cols)
        Regions over the sensor, each ≥ 1 (the paper's 15 × 20).
    channels : sequence of {"R", "G", "B"}
        Channels of ``camera`` under ``illuminant``
        (:func:`calibration.optics.psf.spectral.spectral_response`); at least one.
    method : {"debye", "fft", "huygens"}
        Diffraction model (:mod:`calibration.optics.psf`). "debye" (default) is the
        Huygens sum in the Debye approximation on the requested grid: on e9
        within 0.06 % of the Huygens PSFs' peak at ≈ ¼ of their cost at 32²
        (1/20 at 128²); "fft" costs about the same as "debye" here, but its
        affine pupil map is off by up to 4.5 % of the peak in the corners.
        With the defaults the e9 map is within 0.8 % of the peak (NCC
        ≥ 0.99994, encircled energy at 1 µm within 0.25 %) of a reference
        map (Huygens, 96 pupil samples, 4 wavelengths per channel aimed at
        each), on 6 regions from the centre to the corner
        (``benchmarks/psf.py``).
    n : int, optional
        PSF size (n × n samples, ≥ 1); default :func:`default_psf_n` at
        ``pitch_um``: a :data:`WINDOW_UM` (32 µm) window, at least 32 samples.
    pitch_um : float, optional
        PSF sample spacing, µm, > 0; default half the sensor's pixel pitch.
    pupil_samples : int
        Pupil grid across the stop, samples, ≥ 1.
    n_wavelengths : int, optional
        Gauss nodes per channel, ≥ 1 (default
        :data:`calibration.optics.psf.spectral.DEFAULT_WAVELENGTHS_PER_CHANNEL`).
    camera, illuminant : str
        Names known to :func:`calibration.optics.psf.spectral.spectral_response`.
    aiming : {"real", "paraxial"}
    aim_each_wavelength : bool
        Real aiming at every wavelength, or (default) once per region at the
        primary wavelength — half the tracing for ≤ 0.6 % of the peak on e9
        (:func:`calibration.optics.psf.spectral.polychromatic_psf`).
    symmetry : {"auto", "none"}
        "auto": mirror one quadrant when the lens is coaxial (see the module
        docstring); "none": compute every region.

    Examples
    --------
    >>> PSFMapSettings(grid=(3, 4), channels=("g",)).channels
    ('G',)
    >>> PSFMapSettings(method="zemax")
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: PSFMapSettings.method: unknown PSF method 'zemax'; valid: huygens, fft, debye
    """

    grid: tuple[int, int] = (15, 20)
    channels: tuple[str, ...] = ("R", "G", "B")
    method: str = "debye"
    n: int | None = None
    pitch_um: float | None = None
    pupil_samples: int = 64
    n_wavelengths: int | None = None
    camera: str = DEFAULT_CAMERA
    illuminant: str = "D65"
    aiming: str = "real"
    aim_each_wavelength: bool = False
    symmetry: str = "auto"

    def __post_init__(self):
        def bad(name, why):
            return ConfigError(f"PSFMapSettings.{name}: {why}")

        def positive_int(name, v):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise bad(name, f"must be an integer ≥ 1, got {v!r}")
            return int(v)

        if self.method not in METHODS:
            raise bad("method", f"unknown PSF method {self.method!r}; valid: {', '.join(METHODS)}")
        if self.symmetry not in ("auto", "none"):
            raise bad("symmetry", f"unknown symmetry {self.symmetry!r}; valid: 'auto', 'none'")
        if self.aiming not in ("real", "paraxial"):
            raise bad("aiming", f"unknown aiming {self.aiming!r}; valid: 'real', 'paraxial'")
        try:
            rows, cols = self.grid
        except (TypeError, ValueError):
            raise bad("grid", f"must be (rows, cols), got {self.grid!r}") from None
        object.__setattr__(self, "grid", (positive_int("grid", rows), positive_int("grid", cols)))
        if isinstance(self.channels, str):
            raise bad("channels", f"must be a sequence of 'R', 'G', 'B', got {self.channels!r}")
        channels = tuple(str(c).upper() for c in self.channels)
        if not channels or not set(channels) <= {"R", "G", "B"}:
            raise bad("channels", f"must be one or more of 'R', 'G', 'B', got {self.channels!r}")
        object.__setattr__(self, "channels", channels)
        if self.n is not None:
            object.__setattr__(self, "n", positive_int("n", self.n))
        if self.pitch_um is not None:
            try:
                pitch = float(self.pitch_um)
            except (TypeError, ValueError):
                raise bad("pitch_um", f"must be a positive number of µm, got {self.pitch_um!r}") from None
            if not (math.isfinite(pitch) and pitch > 0):
                raise bad("pitch_um", f"must be a positive number of µm, got {self.pitch_um!r}")
            object.__setattr__(self, "pitch_um", pitch)
        object.__setattr__(self, "pupil_samples", positive_int("pupil_samples", self.pupil_samples))
        if self.n_wavelengths is not None:
            object.__setattr__(self, "n_wavelengths", positive_int("n_wavelengths", self.n_wavelengths))
        object.__setattr__(self, "aim_each_wavelength", bool(self.aim_each_wavelength))


def _region_job(task) -> tuple[np.ndarray, np.ndarray]:
    """:func:`region_task` of one region's (field, centre), the rest of its
    arguments read from the executor's payload (sent to each worker once)."""
    pl, *rest = worker_payload()
    fld, center, dz = task
    return region_task((pl, fld, center, *rest), dz)


def psf_map(lens_or_perturbed: Lens | PerturbedLens, settings: PSFMapSettings | None = None, *,
            sensor: Sensor | None = None, image_dz_mm=None, cache_dir=None, cache: bool = True,
            executor: Executor | None = None) -> PSFMap:
    """PSFs of every sensor region and channel of a (perturbed) lens.

    Parameters
    ----------
    lens_or_perturbed : Lens or PerturbedLens
        Its ``sensor`` (the nominal lens's) defines the regions, unless
        ``sensor`` is given.
    settings : PSFMapSettings, optional
        What to compute (default ``PSFMapSettings()``: 15 × 20 regions,
        R, G, B, the Debye method, a 32 µm window at half a pixel).
    sensor : Sensor, optional
        The sensor whose regions are mapped (default the lens's; centred on
        the optical axis).
    image_dz_mm : (rows, cols) array_like, optional
        Where the sensor's surface lies at each region, mm beyond the
        lens's image plane (+: away from the lens): a focus shift
        (constant), a tilted sensor (linear in x, y) or a curved one. Each
        region's rays are cut at its own plane, so its PSF is the lens's
        own defocus there, aberrations and diffraction included (the
        chief ray's slope moves it by ``dz·tan θ``, as on the sensor).
        Default: 0 everywhere.
    cache_dir : path, optional
        Default ``$ISP_CACHE/psf`` or ``~/.cache/phone-isp/psf``.
    cache : bool
        Read and write the cache.
    executor : isp.runtime.executor.Executor, optional
        Runs the regions (each a task; the lens and wavelength plan are its
        payload); its progress bar counts them. Default: up to 2 worker
        processes, the phone budget, where the machine has the cores, with
        a progress bar (:func:`isp.runtime.executor.pool_executor`). On 2
        free cores (``benchmarks/psf.py``, e9, default settings): nominal
        13.4 s → 7.3 s, perturbed 54.6 s → 24.8 s; with one core busy
        elsewhere, no gain.

    Returns
    -------
    PSFMap
    """
    pl = nominal(lens_or_perturbed)
    s = PSFMapSettings() if settings is None else settings
    if not isinstance(s, PSFMapSettings):
        raise ConfigError(f"settings must be a PSFMapSettings, got {type(s).__name__}")
    rows, cols = s.grid
    channels, method, samples = s.channels, s.method, s.pupil_samples
    camera, illuminant, aiming, aim_each_wavelength = s.camera, s.illuminant, s.aiming, s.aim_each_wavelength
    sensor = pl.lens.sensor if sensor is None else sensor
    if not isinstance(sensor, Sensor):
        raise PSFError(f"sensor must be a calibration.optics.lens.Sensor, got {type(sensor).__name__}")
    pitch = 0.5 * sensor.pixel_pitch_um if s.pitch_um is None else s.pitch_um
    if not (math.isfinite(pitch) and pitch > 0):
        raise PSFError(f"pitch_um must be positive, got {pitch!r} (the sensor's pixel pitch)")
    n = default_psf_n(pitch) if s.n is None else s.n
    n_wl = DEFAULT_WAVELENGTHS_PER_CHANNEL if s.n_wavelengths is None else s.n_wavelengths
    nodes, weights = channel_quadrature(channels, n_wl, camera, illuminant)
    if method != "fft":          # the FFT method checks its own period
        check_window(pl, n, pitch, samples, float(np.min(nodes)))
    dz = _image_dz(image_dz_mm, (rows, cols))
    symmetric = s.symmetry == "auto" and _is_coaxial(pl) and _mirrored(dz)
    settings = {"grid": [rows, cols], "channels": list(channels), "method": method, "n": n, "pitch_um": pitch,
                "pupil_samples": samples, "n_wavelengths": n_wl, "camera": camera, "illuminant": illuminant,
                "aiming": aiming, "aim_each_wavelength": bool(aim_each_wavelength), "symmetric": symmetric,
                "sensor": dataclasses.asdict(sensor)}
    if np.any(dz):
        settings["image_dz_mm"] = dz.tolist()
    key = cache_key(pl, settings)
    path = _cache_dir(cache_dir) / f"{key}.npz"
    if cache and path.exists():
        try:
            hit = PSFMap.from_npz(path)
            if hit.key == key and hit.psfs.shape == (rows, cols, len(channels), n, n):
                return hit
        except (OSError, ValueError, PSFError):
            pass   # unreadable or stale: recompute and overwrite

    centers = region_centers_mm(sensor, (rows, cols))
    if symmetric:
        r_sel = np.arange(rows // 2, rows)       # y ≥ 0
        c_sel = np.arange(cols // 2, cols)       # x ≥ 0
        m = n + 1 - n % 2                        # odd grid: mirrors about its centre sample exactly
    else:
        r_sel, c_sel, m = np.arange(rows), np.arange(cols), n
    rr, cc = np.meshgrid(r_sel, c_sel, indexing="ij")
    todo = list(zip(rr.ravel().tolist(), cc.ravel().tolist()))
    fields = chief_ray_fields(pl, np.array([centers[r, c] for r, c in todo]))
    ex = pool_executor(None, progress=True) if executor is None else executor
    threads = 1 if ex.parallel else None     # FFTs and sums on one thread per worker, as BLAS is
    payload = (pl, nodes, weights, method, samples, m, pitch, aiming, bool(aim_each_wavelength), threads)
    tasks = [(fields[i], centers[r, c], float(dz[r, c])) for i, (r, c) in enumerate(todo)]
    try:
        with ex.bind(payload) as job:
            results = job.map(_region_job, tasks, chunksize=max(1, len(tasks) // (8 * ex.workers)),
                              desc=f"PSF map {rows}×{cols}×{len(channels)} ({method})", unit="region")
    finally:
        if executor is None:
            ex.close()

    nc = len(channels)
    psfs = np.zeros((rows, cols, nc, n, n), dtype=np.float32)
    energy = np.zeros((rows, cols, nc))
    field_map = np.zeros((rows, cols, 2))
    for (r, c), f, (data, e) in zip(todo, fields, results):
        if not symmetric:
            psfs[r, c] = data
            energy[r, c] = e
            field_map[r, c] = f
            continue
        for flip_y in (False, True):
            for flip_x in (False, True):
                r2 = rows - 1 - r if flip_y else r
                c2 = cols - 1 - c if flip_x else c
                if (flip_y and r2 == r) or (flip_x and c2 == c):
                    continue                     # on a symmetry plane: computed, not mirrored
                d = data
                if flip_y:
                    d = d[:, ::-1, :]
                if flip_x:
                    d = d[:, :, ::-1]
                psfs[r2, c2] = d[:, :n, :n]
                energy[r2, c2] = e
                field_map[r2, c2] = (-f[0] if flip_x else f[0], -f[1] if flip_y else f[1])
    sums = psfs.sum(axis=(3, 4), dtype=np.float64)
    psfs /= sums[..., None, None].astype(np.float32)       # renormalise after cropping to n
    worst = float(energy.min())
    if worst < WINDOW_ENERGY_WARN:
        r, c, ch = np.unravel_index(int(np.argmin(energy)), energy.shape)
        warnings.warn(f"PSF map: only {worst:.0%} of the energy of region ({r}, {c}) channel {channels[ch]} falls "
                      f"inside the {n}×{n} window at {pitch:g} µm ({n * pitch:g} µm); the normalised PSFs are "
                      "truncated — increase n (or pitch_um)", UserWarning, stacklevel=2)
    out = PSFMap(psfs, pitch, centers, field_map, channels, sensor, key, tuple(nodes), weights, method, energy,
                 settings)
    if cache:
        out.to_npz(path)
    return out


# -- plotting ------------------------------------------------------------------------------------------

def plot_psf_map(psfmap: PSFMap, path, channel: str | int = "G", *, scale: str = "gamma", gamma: float = 0.5,
                 floor: float = 1e-4, dpi: int = 150) -> Path:
    """Save a mosaic of the map's PSFs (one tile per region, each scaled to
    its own peak) labelled with the object field (θx, θy) in degrees.

    Parameters
    ----------
    psfmap : PSFMap
    path : str or Path
        Image file (format from the suffix, e.g. ``.png``).
    channel : str or int
    scale : {"gamma", "log"}
        ``(I/peak)^gamma``, or ``log10(max(I/peak, floor))`` mapped to [0, 1].
    gamma, floor : float
    dpi : int

    Returns
    -------
    Path
    """
    from matplotlib.figure import Figure

    ci = psfmap.channel_index(channel)
    rows, cols = psfmap.grid
    n = psfmap.n
    tiles = psfmap.psfs[:, :, ci].astype(np.float64)
    tiles = tiles / np.maximum(tiles.max(axis=(2, 3), keepdims=True), 1e-300)
    if scale == "gamma":
        tiles = tiles ** gamma
    elif scale == "log":
        lf = math.log10(floor)
        tiles = (np.log10(np.maximum(tiles, floor)) - lf) / -lf
    else:
        raise PSFError(f"unknown scale {scale!r}; valid: 'gamma', 'log'")
    mosaic = tiles.transpose(0, 2, 1, 3).reshape(rows * n, cols * n)
    fig = Figure(figsize=(max(4.0, cols * 0.75), max(3.0, rows * 0.75) + 0.5))
    ax = fig.add_axes((0.01, 0.01, 0.98, 0.98 - 0.45 / (max(3.0, rows * 0.75) + 0.5)))
    ax.imshow(mosaic, cmap="inferno", vmin=0, vmax=1, interpolation="nearest")
    for r in range(rows):
        for c in range(cols):
            fx, fy = psfmap.field_deg[r, c]
            ax.text(c * n + 0.5, r * n + 0.5, f"{fx:.1f},{fy:.1f}", color="white", fontsize=3.5, va="top",
                    ha="left")
    for k in range(1, cols):
        ax.axvline(k * n - 0.5, color="0.4", lw=0.3)
    for k in range(1, rows):
        ax.axhline(k * n - 0.5, color="0.4", lw=0.3)
    ax.set_xticks([])
    ax.set_yticks([])
    wl = ", ".join(f"{w:.0f}" for w in psfmap.wavelengths_nm)
    fig.suptitle(f"PSF map, channel {psfmap.channels[ci]} ({psfmap.method}, {n}×{n} at {psfmap.pitch_um:g} µm; "
                 f"{'gamma ' + format(gamma, 'g') if scale == 'gamma' else 'log'}; labels θx,θy in °; "
                 f"rows +y down the sensor)\nwavelengths {wl} nm", fontsize=6)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path
