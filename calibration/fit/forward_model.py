"""A fast forward model of slanted-edge SFR over the field.

Fitting a proxy camera (:mod:`calibration.fit.proxy`) evaluates the lens tens of
times per iteration, so rendering a chart and measuring it per evaluation is
out of the question. :class:`SfrModel` predicts the *noise-free* ISO 12233
SFR of every observation directly from the lens:

1. One PSF per field region holding observations (at the region's centre,
   the grid of :attr:`Observations.grid`: the paper's 15 × 20 regions) by
   the same tracing and Debye diffraction as
   :func:`calibration.optics.psf.map.psf_map`, every region's pupil grid traced
   in one call per wavelength. The object field of each region is found
   once, at the nominal lens (a perturbation moves the image by
   micrometres: immaterial to an SFR). Interpolating PSFs or transfers
   from a coarser grid was measured and rejected: on e9, bilinear blending
   from a 9 × 13 grid is 0.007 cycles/pixel RMS off in SFRA, and from a
   polar grid with each node's PSF turned to the observation's azimuth
   0.004 (20 × 8 nodes) — both above the measurement's own noise, because
   a perturbed phone lens's sharpness changes fast across the field.
2. "L" observations mix the R, G, B PSFs with the luminance weights of
   :data:`calibration.sfr.esfr.LUMINANCE_WEIGHTS`.
3. Its transfer along the edge normal n̂ is the projection-slice theorem:
   ``OTF(f n̂) = Σ_i w_i exp(−2πi f n̂·v_i)`` over the PSF's samples
   (masses ``w_i`` at offsets ``v_i``), exact below the first replica of
   the sample lattice (≥ 1.6 cycles/pixel at the default half-pixel PSF
   pitch, so exact on 0..1 cycles/pixel). It is computed by binning the
   masses on the normal at Δ = 1/64 px with linear weights and one DFT
   (the binning moves a mass by < Δ: transfer off by ≤ (πfΔ)²/3, 8e-4 at
   1 cycle/pixel).
4. ``SFR(f) = |OTF(f n̂)| · sinc(a f n_x) sinc(a f n_y)`` (square pixel
   aperture of side ``a``), times any multiplicative transfer the caller
   adds (the loop's effects: crosstalk, sharpening, glare).

Defocus per node (``defocus_mm``: a focus shift, a tilted or curved sensor),
or per node and colour (longitudinal colour), moves the reference plane of
the already traced rays; no retrace. Traced
rays are cached per lens, so effects that only move the plane are cheap.

The measured SFRA is raised by the measurement's own noise (paper eq. 14
simulates it); :meth:`SfrModel.noise_bias` estimates that rise per
observation by rendering its edge through the predicted PSF, adding the
observation's own noise and measuring it as it was measured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from isp.runtime.executor import create_executor, worker_payload

from calibration.optics.lens import Lens, Sensor
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.fit.observations import Observations
from calibration.optics.psf.debye import debye_node_psfs
from calibration.optics.psf.map import WINDOW_UM, check_window, chief_ray_fields, default_psf_n, sensor_to_image
from calibration.optics.psf.methods import monochromatic_samples
from calibration.optics.psf.pupil import exit_pupil_z, nodes_from_trace, pupil_points, reference_sphere
from calibration.optics.psf.sampling import grid_offsets_mm
from calibration.optics.psf.result import sample_centroid_um
from calibration.optics.psf.spectral import DEFAULT_CAMERA, channel_quadrature
from calibration.sfr.esfr import LUMINANCE_WEIGHTS
from calibration.sfr.asymmetry import BANDS as ODD_BANDS
from calibration.sfr.asymmetry import model_odd_bands, odd_bands, project_masses
from calibration.sfr.edge import area_weights

__all__ = ["ModelSettings", "Prediction", "SfrModel", "antithetic_spread", "aperture_mtf", "band_means", "mtf_along",
           "otf_along", "sfra_of"]

BIN_STEP_PX = 1.0 / 64.0
CHANNELS = ("R", "G", "B")


@dataclass(frozen=True)
class ModelSettings:
    """Accuracy/speed settings of :class:`SfrModel`.

``pupil_samples``: pupil grid across the stop. ``window_um``: the PSF
    window's side, µm (a lens's PSF is as wide in µm whatever the pixel),
    sampled at ``psf_pitch_um`` (default half the pixel pitch): an even
    number of samples at least that wide; ``psf_n`` sets the samples
    instead.
    The PSF is normalised inside its window, so the light a window drops
    is missing from the SFR's fall at low frequencies. The default 64 (a
    32 µm window on 1 µm pixels) is measured against narrower ones: on the four
    phone lenses' devices (±1 tolerance) a 16 µm window drops up to 30 %
    of a corner PSF and puts the corner SFR up to 0.116 RMS off a 64 µm
    reference; 32 µm keeps it within 0.018 for 1.2–1.3× the evaluation time
    (48 µm: 0.003 for 2.6–3×; ``benchmarks/psf_window.py``; at 15 × 20
    regions on e9 a prediction takes 1.61 s CPU against 1.31 s at 16 µm,
    ``benchmarks/lens_eval.py --psf-n``). The window must
    stay inside the sampled pupil's replica period ≈ λ·N·``pupil_samples``
    (:func:`calibration.optics.psf.map.check_window`).
    ``n_wavelengths``: Gauss nodes per channel. ``aiming``: "real" (the
    pupil grid is aimed at the real stop once, at the nominal lens) or
    "paraxial" (paraxial entrance pupil: 0.003 cycles/pixel RMS off on e9,
    whose pupil is distorted at the edge of the field).
    ``aperture_px``: side of the square pixel aperture, pixels.
    ``noise_realisations``: noisy renders averaged per observation by
    :meth:`SfrModel.noise_bias`.
    """

    pupil_samples: int = 48
    window_um: float = WINDOW_UM
    psf_n: int | None = None
    psf_pitch_um: float | None = None
    n_wavelengths: int = 2
    aiming: str = "real"
    method: str = "debye"
    camera: str = DEFAULT_CAMERA
    illuminant: str = "D65"
    aperture_px: float = 1.0
    noise_realisations: int = 4
    seed: int = 0

    def with_window(self, window_um: float) -> ModelSettings:
        """These settings with a ``window_um`` window and the pupil grid grown
        with it in this window's ratio (never shrunk), so that a window
        these settings keep inside the pupil sampling's replica period stays
        inside it (:func:`calibration.optics.psf.map.check_window`; ``isp calib fit --window-um``).

        >>> ModelSettings().with_window(48.0).pupil_samples
        72
        """
        grown = math.ceil(self.pupil_samples * float(window_um) / self.window_um)
        return replace(self, window_um=float(window_um), pupil_samples=max(self.pupil_samples, grown))


#: the cheaper model a fit may take its Jacobian from (``--fast-jacobian``): fewer pupil samples, and so a
#: window inside their shorter replica period (:func:`calibration.optics.psf.map.check_window`)
FAST_JACOBIAN = ModelSettings(pupil_samples=32, window_um=24.0)


@dataclass(frozen=True, eq=False)
class Prediction:
    """Predicted noise-free SFRA (N,) and SFR (N, F) on ``freq``."""

    sfra: np.ndarray
    sfr: np.ndarray
    freq: np.ndarray


def sfra_of(freq: np.ndarray, sfr: np.ndarray) -> np.ndarray:
    """Area under each SFR row from 0 to 0.5 cycles/pixel (cycles/pixel),
    as :func:`calibration.sfr.edge.area_to` computes it, for all rows by
    one product with its weights (:func:`calibration.sfr.edge.area_weights`).

    >>> f = np.linspace(0, 0.6, 7)
    >>> float(sfra_of(f, np.ones((2, 7)))[1])
    0.5
    """
    w = area_weights(np.asarray(freq, float), 0.5)
    return np.atleast_2d(sfr)[:, :w.size] @ w


def mtf_along(psf: np.ndarray, pitch_px: float, normal_deg, freq) -> np.ndarray:
    """|:func:`otf_along`|: the MTF of sampled PSFs along edge normals.

    Examples
    --------
    >>> p = np.zeros((9, 9)); p[4, 4] = 1.0
    >>> bool(np.allclose(mtf_along(p, 0.5, [30.0], [0.0, 0.5, 1.0]), 1.0))
    True
    """
    return np.abs(otf_along(psf, pitch_px, normal_deg, freq))


def otf_along(psf: np.ndarray, pitch_px: float, normal_deg, freq) -> np.ndarray:
    """OTF of sampled PSFs along edge normals (projection-slice theorem).

    Parameters
    ----------
    psf : (N, m, m) or (m, m) ndarray
        Masses (rows +y down the sensor), centred at ``m // 2``.
    pitch_px : float
        Sample spacing, pixels.
    normal_deg : (N,) array_like
        Normal directions, degrees CCW from +x with y down.
    freq : (F,) array_like
        Cycles/pixel.

    Returns
    -------
    (N, F) complex ndarray
        Phase relative to the PSF's centre sample.
    """
    hist, x = project_masses(psf, pitch_px, normal_deg, BIN_STEP_PX)
    ph = 2.0 * np.pi * x[:, None] * np.asarray(freq, dtype=np.float64)[None, :]
    return hist @ np.cos(ph) - 1j * (hist @ np.sin(ph))


def aperture_mtf(freq, normal_deg, a: float = 1.0) -> np.ndarray:
    """Transfer of a square pixel aperture of side ``a`` px along normals:
    ``|sinc(a f cos θ) sinc(a f sin θ)|``, (N, F)."""
    t = np.radians(np.asarray(normal_deg, dtype=np.float64))[:, None]
    f = np.asarray(freq, dtype=np.float64)[None, :]
    return np.abs(np.sinc(a * f * np.cos(t)) * np.sinc(a * f * np.sin(t)))


class SfrModel:
    """Predicts the observations' SFR for any perturbation of ``nominal``
    (module docstring).

    Parameters
    ----------
    nominal : Lens
    obs : Observations
    settings : ModelSettings, optional
    """

    def __init__(self, nominal_lens: Lens, obs: Observations, settings: ModelSettings | None = None):
        self.nominal = nominal_lens
        self.obs = obs
        self.settings = s = settings or ModelSettings()
        self.sensor: Sensor = obs.sensor
        sen = self.sensor
        # one node per field region holding observations, at the region's centre
        reg = obs.region
        self.regions, self.obs_node = np.unique(reg, axis=0, return_inverse=True)
        self.obs_node = self.obs_node.reshape(-1)
        rows, cols = obs.grid
        x_px = (self.regions[:, 1] + 0.5) * sen.width_px / cols - 0.5
        y_px = (self.regions[:, 0] + 0.5) * sen.height_px / rows - 0.5
        xm, ym = sensor_to_image(x_px, y_px, sen)
        self.node_px = np.stack([x_px, y_px], axis=1)
        self.node_mm = np.stack([xm, ym], axis=1)
        self.fields = chief_ray_fields(nominal(nominal_lens), self.node_mm)
        self.pitch_um = 0.5 * sen.pixel_pitch_um if s.psf_pitch_um is None else float(s.psf_pitch_um)
        self.pitch_px = self.pitch_um / sen.pixel_pitch_um
        # the window is set in µm, not samples: a fixed 64 samples would make 90 µm on 2.8 µm pixels,
        # past the pupil sampling's replica period
        self.psf_n = int(s.psf_n) if s.psf_n is not None else default_psf_n(self.pitch_um, s.window_um, minimum=2)
        used = set(np.asarray(obs.channel).tolist())
        self.channels = tuple(c for c in CHANNELS if c in used or "L" in used)
        if not self.channels:
            raise ValueError(f"observations have no R, G, B or L channel (got {sorted(used)})")
        self.wavelengths, self.wl_weights = channel_quadrature(self.channels, s.n_wavelengths, s.camera,
                                                             s.illuminant)
        check_window(nominal_lens, self.psf_n, self.pitch_um, s.pupil_samples, float(np.min(self.wavelengths)),
                     fix="a smaller window_um")
        self.mix = self._channel_mix()
        self._aim = _real_aim(nominal(nominal_lens), self.fields, s.pupil_samples) if s.aiming == "real" else None
        self._traced_key = None
        self._traced = None
        self._mtf_cache = (None, None)
        self._psf_cache = (None, None)

    # -- geometry ----------------------------------------------------------------------
    def _channel_mix(self) -> np.ndarray:
        """(N, channels) weights of each observation's colour."""
        mix = np.zeros((len(self.obs), len(self.channels)))
        lum = dict(zip(CHANNELS, LUMINANCE_WEIGHTS))
        for i, ch in enumerate(np.asarray(self.obs.channel)):
            for c, w in (lum.items() if ch == "L" else ((ch, 1.0),)):
                if c in self.channels:
                    mix[i, self.channels.index(c)] = w
        return mix / mix.sum(axis=1, keepdims=True)

    @staticmethod
    def _trace_key_of(lens) -> tuple:
        pl = nominal(lens)
        return repr(pl.perturbation.as_dict()), id(pl.nominal)

    def _trace(self, lens: PerturbedLens) -> list:
        """Traced rays of every node, one :class:`calibration.optics.psf.pupil.TracedNodes`
        per wavelength, cached for the last lens."""
        key = self._trace_key_of(lens)
        if self._traced_key == key:
            return self._traced
        s = self.settings
        z_pupil = exit_pupil_z(lens)
        traced = _trace_nodes(lens, self.fields, self.wavelengths, s.pupil_samples, z_pupil, self._aim)
        self._traced_key, self._traced = key, traced
        return traced

    def node_psfs(self, lens, defocus_mm=None) -> np.ndarray:
        """(nodes, channels, m, m) PSFs, each node's centred on its chief
        ray at the primary wavelength; ``defocus_mm`` (scalar, per node
        (nodes,), or per node and channel (nodes, channels)) moves the
        image plane along the axis (+: away from the lens); with one plane
        per channel each wavelength is traced to the planes of the channels
        it counts in, and each channel's PSFs are centred on the chief ray
        in its own plane.

        The traced rays (and their pupil fit,
        :attr:`calibration.optics.psf.pupil.TracedNodes.jac`) are reused; a new plane
        recomputes the reference spheres and the
        diffraction sums, all nodes at once for the "debye" method
        (:func:`calibration.optics.psf.debye.debye_node_psfs`; the others node by node)."""
        return self._node_psfs(lens, defocus_mm)[0]

    def _node_psfs(self, lens, defocus_mm=None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`node_psfs` and each node's window energy per channel (nodes, channels)."""
        pl = nominal(lens)
        s = self.settings
        traced = self._trace(pl)
        k = len(self.regions)
        dz = np.asarray(0.0 if defocus_mm is None else defocus_mm, float)
        planes = ([np.broadcast_to(dz, (k,))] if dz.ndim < 2 else
                  [np.broadcast_to(dz, (k, len(self.channels)))[:, c] for c in range(len(self.channels))])
        o = grid_offsets_mm(self.psf_n, self.pitch_um)
        ref = int(np.argmin(np.abs(self.wavelengths - pl.nominal.primary_nm)))
        out = np.zeros((k, len(self.channels), self.psf_n, self.psf_n))
        energy = np.zeros((k, len(self.channels)))
        for q, d in enumerate(planes):
            # one plane for every channel, or channel q's own
            weights = self.wl_weights if len(planes) == 1 else np.eye(len(self.channels))[:, [q]] * self.wl_weights
            z = traced[ref].z_image + d
            centre = traced[ref].chief_image_points(z)
            for j, tn in enumerate(traced):
                if not np.any(weights[:, j]):
                    continue
                if s.method == "debye":
                    data, e = debye_node_psfs(tn, centre, z, o, o, energy=True)
                else:
                    pairs = [monochromatic_samples(reference_sphere(tn.node(i, z[i]), centre[i]), s.method, o, o,
                                                   workers=1) for i in range(k)]
                    data, e = np.stack([p[0] for p in pairs]), np.array([p[1] for p in pairs])
                out += weights[None, :, j, None, None] * data[:, None]
                energy += weights[None, :, j] * e[:, None]
        return out, energy

    # -- prediction ----------------------------------------------------------------------
    def observation_psfs(self, lens, defocus_mm=None) -> np.ndarray:
        """(N, m, m): each observation's PSF in its colour (its region's),
        cached for the last lens and defocus (the SFR and the asymmetry of
        one evaluation share them)."""
        return self._observation_psfs(lens, defocus_mm)[0]

    def window_energy(self, lens, defocus_mm=None) -> np.ndarray:
        """(N,) the fraction of each observation's light that lands in its
        PSF window (``PSF.window_energy`` of :mod:`calibration.optics.psf.result`, mixed
        as the observation's colour): 1 − the far tails the window drops."""
        return self._observation_psfs(lens, defocus_mm)[1]

    def _observation_psfs(self, lens, defocus_mm=None) -> tuple[np.ndarray, np.ndarray]:
        key = (self._trace_key_of(lens), None if defocus_mm is None else np.asarray(defocus_mm, float).tobytes())
        if self._psf_cache[0] != key:
            p, energy = self._node_psfs(lens, defocus_mm)
            e = np.clip(np.einsum("nc,nc->n", self.mix, energy[self.obs_node]), 0.0, 1.0)
            self._psf_cache = (key, (np.einsum("nc,ncij->nij", self.mix, p[self.obs_node]), e))
        return self._psf_cache[1]

    def predict_odd(self, lens, defocus_mm=None) -> np.ndarray:
        """(N, K) noise-free LSF asymmetry of every observation: the band
        means of :func:`calibration.sfr.asymmetry.model_odd_bands` (the odd part
        of the transfer that SFR drops)."""
        return model_odd_bands(self.observation_psfs(lens, defocus_mm), self.pitch_px, self.obs.normal_deg,
                               aperture_px=self.settings.aperture_px)

    def optical_mtf(self, lens, defocus_mm=None, shifts_px=None) -> np.ndarray:
        """(N, F) |OTF| of the optics along each observation's normal.
        ``shifts_px`` (N, channels, 2): extra lateral shift (x, y) of each
        channel's PSF (lateral colour), which matters only where an
        observation mixes channels ("L")."""
        obs = self.obs
        if shifts_px is None:
            key = (self._trace_key_of(lens), None if defocus_mm is None else np.asarray(defocus_mm, float).tobytes())
            if self._mtf_cache[0] != key:
                self._mtf_cache = (key, mtf_along(self.observation_psfs(lens, defocus_mm), self.pitch_px,
                                                  obs.normal_deg, obs.freq))
            return self._mtf_cache[1]
        p = self.node_psfs(lens, defocus_mm)[self.obs_node]            # (N, C, m, m)
        t = np.radians(np.asarray(obs.normal_deg, float))
        f = np.asarray(obs.freq, float)
        total = np.zeros((len(obs), len(f)), complex)
        for c in range(len(self.channels)):
            w = self.mix[:, c]
            if not np.any(w):
                continue
            d = shifts_px[:, c, 0] * np.cos(t) + shifts_px[:, c, 1] * np.sin(t)
            total += w[:, None] * otf_along(p[:, c], self.pitch_px, obs.normal_deg, f) \
                * np.exp(-2j * np.pi * f[None, :] * d[:, None])
        return np.abs(total)

    def predict(self, lens, *, defocus_mm=None, transfer=None, shifts_px=None) -> Prediction:
        """Noise-free SFR and SFRA of every observation.

        Parameters
        ----------
        lens : Lens or PerturbedLens
        defocus_mm : float, (nodes,) or (nodes, channels) array, optional
            Image-plane shift per node, or per node and channel
            (longitudinal colour; see :meth:`node_psfs`).
        transfer : (N, F) array, optional
            Extra multiplicative transfer (sensor MTF, sharpening, glare).
        """
        obs = self.obs
        sfr = self.optical_mtf(lens, defocus_mm, shifts_px) * aperture_mtf(obs.freq, obs.normal_deg, self.settings.aperture_px)
        if transfer is not None:
            sfr = sfr * transfer
        return Prediction(sfra_of(obs.freq, sfr), sfr, obs.freq)

    # -- the measurement's own noise and method ---------------------------------------------
    def noise_bias(self, lens, obs: Observations | None = None, *, psfs=None) -> np.ndarray:
        """SFRA part of :meth:`measurement_bias` (N,), cycles/pixel."""
        return self.measurement_bias(lens, obs, psfs=psfs)[0]

    def measurement_bias(self, lens, obs: Observations | None = None, *, psfs=None) -> tuple[np.ndarray, np.ndarray]:
        """What the measurement adds to each observation's SFRA (N,),
        cycles/pixel: the mean SFRA of ``noise_realisations`` renders of its
        edge through its predicted PSF with its own noise, measured as it
        was measured (``obs.meta["measure"]``: "image", "bayer:<channel>" or
        "raw", the mosaic, each edge on its own channel; ``obs.meta["cfa"]``),
        minus the model's noise-free SFRA. It holds the noise's rise (paper
        eq. 14) and the ISO method's own small bias (its binning and
        derivative: +0.001 cycles/pixel on e9 noise-free). Returns
        ``(sfra_bias (N,), sfr_bias (N, F))``, the second the same for the
        SFR curves on ``obs.freq``; :meth:`measurement_biases` adds the
        asymmetry's."""
        b = self.measurement_biases(lens, obs, psfs=psfs)
        return b.sfra, b.sfr

    def measurement_biases(self, lens, obs: Observations | None = None, *, psfs=None,
                           executor=None) -> "MeasurementBias":
        """:meth:`measurement_bias` and the same for the LSF asymmetry
        (:mod:`calibration.sfr.asymmetry`; the model already carries ISO's
        binning and derivative, so this is the noise's and the record's
        small part), from the same renders. Each observation draws its
        noise from its own seed, so an ``executor`` (an
        :class:`isp.runtime.executor.Executor`; default: this process) of
        several workers (600 observations: 9.4 s on one process, 5.4 s on
        two) gives the same numbers as one; the PSFs go to each worker
        once, as its payload."""
        obs = self.obs if obs is None else obs
        s = self.settings
        psfs = self.observation_psfs(lens) if psfs is None else psfs
        exact = (mtf_along(psfs, self.pitch_px, obs.normal_deg, obs.freq)
                 * aperture_mtf(obs.freq, obs.normal_deg, s.aperture_px))
        exact_a = sfra_of(obs.freq, exact)
        exact_odd = model_odd_bands(psfs, self.pitch_px, obs.normal_deg, aperture_px=s.aperture_px)
        out = np.zeros(len(obs))
        spread = np.zeros((len(obs), 1 + len(BANDS)))
        curves = np.zeros_like(exact)
        odd = np.zeros_like(exact_odd)
        job = dict(psfs=psfs, pitch_um=self.pitch_um, pixel_pitch_um=self.sensor.pixel_pitch_um, obs=obs,
                   n_real=s.noise_realisations, seed=s.seed, aperture_px=s.aperture_px)
        ex = executor
        if ex is None or not ex.parallel or len(obs) < 2 * ex.workers:
            ex = create_executor("serial")      # too few observations to pay for starting workers
        with ex.bind(job) as run:
            results = run.map(_bias_task, range(len(obs)), chunksize=max(1, len(obs) // (4 * ex.workers)))
        for i, (m, c, sd, q) in enumerate(results):
            out[i] = m - exact_a[i] if np.isfinite(m) else 0.0
            curves[i] = np.where(np.isfinite(c), c - exact[i], 0.0)
            odd[i] = np.where(np.isfinite(q), q - exact_odd[i], 0.0)
            spread[i] = sd
        return MeasurementBias(out, curves, odd, spread)


def _bias_task(i: int) -> tuple:
    j = worker_payload()        # measurement_biases's job, sent to each worker once
    return _measured_sfra(j["psfs"][i], j["pitch_um"], j["pixel_pitch_um"], j["obs"], i, j["n_real"],
                          np.random.default_rng((j["seed"], i)), j["aperture_px"])


class MeasurementBias(NamedTuple):
    """What the measurement adds to the model's noise-free prediction:
    SFRA (N,), SFR curves (N, F) and LSF asymmetry bands (N, K); and
    ``noise`` (N, 1 + len(BANDS)), the standard deviation of one noisy
    measurement's SFRA and of its mean SFR in each of :data:`BANDS`, from
    the same renders (:func:`antithetic_spread`), cycles/pixel."""

    sfra: np.ndarray
    sfr: np.ndarray
    odd: np.ndarray
    noise: np.ndarray | None = None


def _real_aim(pl: PerturbedLens, fields, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Per field: the paraxial entrance-pupil coordinates at which real
    aiming (primary wavelength, nominal lens) puts the pupil grid and the
    chief ray on the stop, (K, M + 1, 2), and the aiming status (K, M + 1)
    — as ``trace_pupils(aim_each=False)`` (:mod:`calibration.optics.psf.pupil`) does, computed once: a perturbation
    within tolerance moves these by far less than a pupil sample. All
    fields are aimed together (:func:`calibration.optics.trace.field_pupil_rays`)."""
    from calibration.optics.trace import field_pupil_rays, stop_and_pupil

    pc = pupil_points(samples)
    pp = stop_and_pupil(pl)
    f = np.asarray(fields, dtype=np.float64).reshape(-1, 2)
    r0 = field_pupil_rays(pl, f, pc, float(pl.nominal.primary_nm), aiming="real")
    t = (pp.z - r0.origin[:, 2]) / r0.direction[:, 2]
    ep = (r0.origin[:, :2] + t[:, None] * r0.direction[:, :2]) / pp.radius
    return ep.reshape(len(f), len(pc), 2), r0.status.reshape(len(f), len(pc))


def _trace_nodes(pl: PerturbedLens, fields, wavelengths, samples: int, z_pupil: float, aim=None) -> list:
    """:func:`calibration.optics.psf.pupil.trace_pupil` for many fields at once: every
    field's pupil grid and chief ray generated and traced in one call per
    wavelength (per call, the tracer's and the ray set-up's overhead would
    dominate at a few thousand rays). ``aim``: the per-field entrance-pupil
    points and statuses of :func:`_real_aim` (else paraxial aiming of the
    plain grid). Returns one :class:`calibration.optics.psf.pupil.TracedNodes` per
    wavelength."""
    from calibration.optics.trace import field_pupil_rays, trace_to_exit

    pupil = pupil_points(samples)
    ep, status = (pupil, None) if aim is None else aim
    f = np.asarray(fields, dtype=np.float64).reshape(-1, 2)
    out = []
    for lam in wavelengths:
        rays = field_pupil_rays(pl, f, ep, float(lam), status=status)
        out.append(nodes_from_trace(pl, rays, trace_to_exit(pl, rays), f, pupil[:-1], samples, z_pupil))
    return out


def measure_like(obs: Observations, i: int):
    """The e-SFR measurement observation ``i`` had, as a function of an
    ROI image, with the method it was measured by (``obs.meta["sfr_method"]``;
    a set that names none was measured by the standard's, "iso"):
    :func:`calibration.sfr.esfr.measure_sfr` on an image
    (``obs.meta["measure"]`` "image", the default), or
    :func:`calibration.sfr.esfr.measure_sfr_bayer` on the plane of one channel of
    a mosaic ("bayer:<channel>"; "raw": each edge on its own channel's
    plane, as `isp calib loop` and `isp calib fit` measure a raw capture),
    its pattern ``obs.meta["cfa"]`` (default RGGB).

    Measuring "raw" observations as images instead would make their spread
    too small: on a 2.8 µm-pixel capture (`isp calib simulate`) the loop's
    noise floor read 0.0026 cycles/pixel that way, where two noise draws of
    the capture scatter by 0.011 per edge (0.0055 measured as here;
    ``benchmarks/capture_roundtrip.py``).
    """
    from calibration.sfr.esfr import measure_sfr, measure_sfr_bayer

    how = str(obs.meta.get("measure", "image"))
    method = str(obs.meta.get("sfr_method", "iso"))
    if how == "raw":
        how = f"bayer:{obs.channel[i]}"
    if how.startswith("bayer:"):
        cfa, channel = str(obs.meta.get("cfa", "RGGB")), how.split(":", 1)[1]
        return lambda img: measure_sfr_bayer(img, cfa, channel=channel, method=method)
    return lambda img: measure_sfr(img, method=method)


def _roi_shape(obs: Observations, i: int) -> tuple[int, int]:
    if obs.roi is not None:
        w, h = int(obs.roi[i][2]), int(obs.roi[i][3])
        return max(h, 16), max(w, 16)
    return (96, 64) if obs.orientation[i] != "horizontal" else (64, 96)


def render_observation(psf, pitch_um, pixel_pitch_um, obs, i, aperture_px) -> np.ndarray:
    """Observation ``i``'s edge rendered noise-free through ``psf`` (sampled
    at ``pitch_um``, centre at ``n // 2``) as the measurement saw it: its
    ROI's shape as measured (rows × columns), its normal, its step on a 0.25
    floor, and, where the observation keeps its ROI, the edge where it was
    measured in it (``x_px, y_px`` less the ROI's corner), less the PSF's
    own centroid shift along the normal (the measured place holds it
    already). The edge's place in its ROI sets which phases the few rows of a
    Bayer plane sample: on a simulated 2.8 µm-pixel capture, rendering a
    32 × 42 ROI as 42 × 32 through its centre put a 0.0066 RMS (up to
    0.016) difference between the measured SFRA of the capture's edge and
    of its render through the same PSF, the true shape 0.0042, the measured
    place 0.0034, the place less the PSF's shift 0.0009."""
    from types import SimpleNamespace

    from calibration.simulate.capture import render_slanted_edge

    step = float(obs.step[i]) or 1.0
    a = float(obs.normal_deg[i]) % 180.0
    horizontal = 45.0 <= a < 135.0
    angle = a - 90.0 if horizontal else (-a if a <= 45.0 else 180.0 - a)
    h, w = _roi_shape(obs, i)
    centre = ((w - 1) / 2.0, (h - 1) / 2.0)
    edge = centre
    if obs.roi is not None:
        rx, ry = float(obs.roi[i][0]), float(obs.roi[i][1])
        sx, sy = sample_centroid_um(psf, pitch_um) / pixel_pitch_um
        edge = (float(obs.x_px[i]) - rx - sx, float(obs.y_px[i]) - ry - sy)
    r = render_slanted_edge(SimpleNamespace(data=psf, pitch_um=pitch_um), centre, (h, w), angle,
                            horizontal=horizontal, low=0.25, high=0.25 + step, pixel_pitch_um=pixel_pitch_um,
                            fill_factor=aperture_px, noise=False, edge_px=edge)
    return r.optical[:, :, 0]


def antithetic_spread(values) -> np.ndarray:
    """Standard deviation of one noisy measurement from antithetic pairs:
    ``values`` (2P, ...) are measurements of clean + n_p and clean − n_p,
    pair by pair. A measurement is m₀ + o(n) + e(n), o odd and e even in
    the noise; the half-differences are o, the pair means m₀ + e, so
    Var = mean(o²) + Var(pair means) (the latter from P ≥ 2 pairs). The
    half-differences alone miss the even part, which a magnitude such as
    the SFR has: on e1's device they read 0.89 of the spread between two
    captures, both parts together 1.00.

    >>> v = np.array([1.0, -1.0, 3.0, 1.0])          # o = ±1, pair means 0 and 2
    >>> float(antithetic_spread(v))
    1.7320508075688772
    """
    v = np.asarray(values, float)
    half = 0.5 * (v[0::2] - v[1::2])
    var = np.nanmean(half ** 2, axis=0)
    if len(v) >= 4:
        var = var + np.nanvar(0.5 * (v[0::2] + v[1::2]), axis=0, ddof=1)
    return np.sqrt(var)


def _measured_sfra(psf, pitch_um, pixel_pitch_um, obs, i, n_real, rng, aperture_px) -> tuple:
    """Mean measured SFRA, SFR curve, spread (SFRA and :data:`BANDS`,
    :func:`antithetic_spread`) and LSF asymmetry bands of observation
    ``i``'s edge rendered through ``psf`` with its noise (noise-free once
    if it has none)."""
    from calibration.sfr.esfr import SfrError

    noise = float(obs.noise[i])
    clean = render_observation(psf, pitch_um, pixel_pitch_um, obs, i, aperture_px)
    measure = measure_like(obs, i)

    f = np.asarray(obs.freq)

    n_odd = len(ODD_BANDS)

    def sfra(img):
        try:
            r = measure(img)
        except SfrError:
            return np.nan, np.full(f.shape, np.nan), np.full(n_odd, np.nan)
        return r.sfra, np.interp(f, r.freq, r.sfr, right=np.nan), odd_bands(r.lsf, r.esf_step_px)

    # antithetic pairs (clean ± the same noise): the measured SFR's first-order response to the
    # noise cancels within each pair, leaving the even part, the noise's bias, to be averaged
    draws = [rng.normal(0.0, noise, clean.shape) for _ in range(max(1, (n_real + 1) // 2))] if noise > 0 else []
    imgs = [clean] if not draws else [clean + sgn * d for d in draws for sgn in (1.0, -1.0)]
    vals = [sfra(img) for img in imgs]
    a = np.array([v[0] for v in vals])
    c = np.array([v[1] for v in vals])
    q = np.array([v[2] for v in vals])
    nb = 1 + len(BANDS)
    if not np.isfinite(a).any():
        return float("nan"), np.full(f.shape, np.nan), np.full(nb, np.nan), np.full(n_odd, np.nan)
    with np.errstate(invalid="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            # the spread of one noisy measurement (the pairs' members are anti-correlated, so the
            # values' own spread would read high): SFRA and the band means
            sd = (antithetic_spread(np.concatenate([a[:, None], band_means(f, c)], axis=1)) if draws
                  else np.full(nb, np.nan))
            return float(np.nanmean(a)), np.nanmean(c, axis=0), sd, np.nanmean(q, axis=0)


#: frequency bands (cycles/pixel) whose mean SFR joins SFRA as a residual: SFRA
#: alone (one number per edge) does not pin the curve's shape
BANDS = ((0.02, 0.125), (0.125, 0.25), (0.25, 0.375), (0.375, 0.5))


def band_means(freq, sfr, bands=BANDS) -> np.ndarray:
    """Mean of each row of ``sfr`` (N, F) over each of ``bands`` (default
    :data:`BANDS`), (N, K).

    >>> import numpy as np
    >>> band_means(np.linspace(0, 1, 129), np.ones((2, 129))).shape
    (2, 4)
    """
    f = np.asarray(freq)
    out = []
    for lo, hi in bands:
        m = (f >= lo) & (f <= hi)
        out.append(np.nanmean(np.asarray(sfr)[:, m], axis=1))
    return np.stack(out, axis=1)
