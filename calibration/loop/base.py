"""Base models for the loop closure (:mod:`calibration.loop.closure`).

A base model predicts every observation's SFR from its own parameters plus
the hooks of added effects (:mod:`calibration.loop.effects`):

* :class:`LensBase` — a lens prescription and its perturbations
  (:class:`calibration.fit.forward_model.SfrModel`); its parameters are
  every toleranced perturbation of the lens and its focus
  (:data:`BASE_KINDS`): a device with every tolerance drawn needs them
  all to reach the noise floor. A focus shift within the base's range
  (:data:`calibration.fit.proxy.FOCUS_BOUND`: ±80 µm, the range a
  device's best focus takes) is the lens's focus parameter, reported with
  the base's parameters; the ``focus_shift`` effect finds what lies beyond.
* :class:`ParametricBase` — no prescription (an unknown camera): a
  diffraction-limited circular pupil at F-number N (ISO 12233 Annex /
  Goodman eq. 6-33) × a Gaussian aberration blur of σ px × the square pixel
  aperture. Defocus Δz adds a uniform disc of diameter |Δz|/N (geometric
  optics); lateral colour shifts the colour planes of mixed ("L") edges
  (:func:`colour_shift_mtf`). Its measurement bias renders the model's own
  edge (:func:`edge_profile`) through the ISO measurement, so that what the
  LSF record window does to the diffraction tails is in the model.
"""

from __future__ import annotations

import math

import numpy as np

from calibration.loop.effects import Geometry
from calibration.fit.observations import Observations
from calibration.fit.forward_model import BANDS, Prediction, aperture_mtf, band_means, measure_like, sfra_of
from calibration.fit.proxy import ALL_KINDS

__all__ = ["BASE_KINDS", "LensBase", "ParametricBase", "area_weights", "colour_shift_mtf", "diffraction_mtf", "disc_mtf",
           "disc_otf", "edge_profile", "make_base"]


def diffraction_mtf(f_cy_per_mm, wavelength_nm: float, f_number: float) -> np.ndarray:
    """MTF of an aberration-free circular pupil (Goodman, *Introduction to
    Fourier Optics*, eq. 6-33): (2/π)(φ − cos φ sin φ), φ = acos(f/fc),
    fc = 1/(λN).

    >>> float(diffraction_mtf(0.0, 550.0, 2.0)), round(float(diffraction_mtf(1e6 / 1100.0, 550.0, 2.0)), 12)
    (1.0, 0.0)
    """
    fc = 1.0 / (wavelength_nm * 1e-6 * f_number)
    v = np.clip(np.abs(np.asarray(f_cy_per_mm, float)) / fc, 0.0, 1.0)
    phi = np.arccos(v)
    return (2.0 / np.pi) * (phi - np.cos(phi) * np.sin(phi))


def disc_otf(f, diameter) -> np.ndarray:
    """2 J₁(πDf)/(πDf): the OTF of a uniform disc of diameter D (same length
    unit as 1/f). Real and signed: it changes sign past each zero
    (πDf = 3.83, 7.02, ...), where the blurred image's contrast reverses.
    A PSF is built from the signed OTF; its modulus is :func:`disc_mtf`.

    >>> float(disc_otf(0.0, 4.0)), bool(disc_otf(0.4, 4.0) < 0)
    (1.0, True)
    """
    from scipy.special import j1

    x = np.pi * np.asarray(diameter, float) * np.asarray(f, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.abs(x) < 1e-9, 1.0, 2.0 * j1(x) / np.where(x == 0, 1.0, x))


def disc_mtf(f, diameter) -> np.ndarray:
    """|2 J₁(πDf)/(πDf)|: the MTF of a uniform disc of diameter D (same
    length unit as 1/f); the modulus of :func:`disc_otf`."""
    return np.abs(disc_otf(f, diameter))


def _geometry(obs: Observations, x_mm, y_mm, channels) -> Geometry:
    cx, cy = (obs.sensor.width_px - 1) / 2.0, (obs.sensor.height_px - 1) / 2.0
    half_px = 0.5 * math.hypot(obs.sensor.width_px, obs.sensor.height_px)
    half_mm = half_px * obs.sensor.pixel_pitch_um * 1e-3
    xy = np.stack([np.asarray(obs.x_px) - cx, np.asarray(obs.y_px) - cy], axis=1)
    normal = np.asarray(obs.normal_deg, float)
    ext = _roi_extent(obs)
    across = None if ext is None else ext[0]
    return Geometry(np.asarray(x_mm, float), np.asarray(y_mm, float), np.hypot(x_mm, y_mm) / half_mm,
                    normal, np.asarray(obs.freq, float), np.asarray(obs.channel),
                    np.asarray(obs.radius, float), xy, tuple(channels), half_px, across)


def _roi_extent(obs: Observations):
    """(across (N,), along (N,)) px of each edge ROI — across the edge: its
    width for a near-vertical edge (normal near 0°/180°), else its height —
    or None where the observations carry no ROIs."""
    if obs.roi is None:
        return None
    roi = np.asarray(obs.roi, float)
    t = np.radians(np.asarray(obs.normal_deg, float))
    vertical = np.abs(np.cos(t)) >= np.abs(np.sin(t))
    return np.where(vertical, roi[:, 2], roi[:, 3]), np.where(vertical, roi[:, 3], roi[:, 2])


def _channel_mix(obs: Observations, channels) -> np.ndarray:
    """(N, channels) weights of each observation's colour: its own channel,
    or the luminance weights for "L" (as :class:`SfrModel` mixes them)."""
    from calibration.sfr.esfr import LUMINANCE_WEIGHTS
    from calibration.fit.forward_model import CHANNELS

    lum = dict(zip(CHANNELS, LUMINANCE_WEIGHTS))
    mix = np.zeros((len(obs), len(channels)))
    for i, ch in enumerate(np.asarray(obs.channel)):
        for c, w in (lum.items() if ch == "L" else ((ch, 1.0),)):
            if c in channels:
                mix[i, channels.index(c)] = w
    s = mix.sum(axis=1, keepdims=True)
    return np.divide(mix, s, out=np.zeros_like(mix), where=s > 0)


def colour_shift_mtf(mix, shifts_px, normal_deg, freq) -> np.ndarray:
    """(N, F) |Σ_c w_c exp(−2πi f d_c)|: the transfer of an edge whose
    colour channels c (weights ``mix`` (N, C), summing to 1) share one PSF
    but lie ``shifts_px`` (N, C, 2) apart (x, y px, y down); d_c is the shift
    along the edge normal. 1 for a single-channel edge: lateral colour is
    seen only where an edge mixes colours.

    >>> float(colour_shift_mtf([[0.5, 0.5]], [[[0.0, 0.0], [1.0, 0.0]]], [0.0], [0.5])[0, 0]) < 1e-12
    True
    """
    t = np.radians(np.asarray(normal_deg, float))
    s = np.asarray(shifts_px, float)
    d = s[:, :, 0] * np.cos(t)[:, None] + s[:, :, 1] * np.sin(t)[:, None]            # (N, C)
    f = np.asarray(freq, float)
    ph = np.exp(-2j * np.pi * d[:, :, None] * f[None, None, :])                       # (N, C, F)
    return np.abs(np.einsum("nc,ncf->nf", np.asarray(mix, float), ph))


class ParametricBase:
    """Parametric optical MTF (module docstring). Parameters: ``sigma_px``
    (aberration blur) and, with ``fit_f_number``, ``f_number``. Nodes are
    the observations themselves (no PSFs to interpolate)."""

    refit_in_cv = True     # cheap: the loop re-fits it with each candidate effect

    def __init__(self, obs: Observations, *, f_number: float = 2.0, wavelength_nm: float = 550.0,
                 fit_f_number: bool = False, aperture_px: float = 1.0):
        self.obs = obs
        self.f_number = float(f_number)
        self.wavelength_nm = float(wavelength_nm)
        self.aperture_px = aperture_px
        self.names = ("sigma_px",) + (("f_number",) if fit_f_number else ())
        self.x0 = np.array([0.5] + ([f_number] if fit_f_number else []))
        self.lower = np.array([0.0] + ([0.7] if fit_f_number else []))
        self.upper = np.array([6.0] + ([16.0] if fit_f_number else []))
        self.scale = np.array([0.2] + ([0.2] if fit_f_number else []))
        pitch_mm = obs.sensor.pixel_pitch_um * 1e-3
        cx, cy = (obs.sensor.width_px - 1) / 2.0, (obs.sensor.height_px - 1) / 2.0
        used = set(np.asarray(obs.channel).tolist())
        channels = ("R", "G", "B") if "L" in used else tuple(c for c in ("R", "G", "B") if c in used) or ("G",)
        self.geometry = _geometry(obs, (np.asarray(obs.x_px) - cx) * pitch_mm, (np.asarray(obs.y_px) - cy) * pitch_mm,
                                  channels)
        self._mix = _channel_mix(obs, channels)
        self._ap = aperture_mtf(obs.freq, obs.normal_deg, aperture_px)
        self._area_w = area_weights(obs.freq)
        self.description = (f"parametric optics: diffraction at f/{self.f_number:g} ({self.wavelength_nm:g} nm) "
                            "× Gaussian aberration blur × pixel aperture")

    def predict(self, xb, *, defocus_mm=None, shifts_px=None, transfer=None) -> Prediction:
        obs = self.obs
        sigma = float(xb[0])
        n = float(xb[1]) if len(xb) > 1 else self.f_number
        f = np.asarray(obs.freq, float)[None, :]
        pitch_mm = obs.sensor.pixel_pitch_um * 1e-3
        sfr = diffraction_mtf(f / pitch_mm, self.wavelength_nm, n) * np.exp(-2 * np.pi ** 2 * sigma ** 2 * f ** 2)
        sfr = sfr * self._ap
        if defocus_mm is not None:
            d_px = np.abs(np.asarray(defocus_mm, float)) / n / pitch_mm
            if d_px.ndim == 1:
                sfr = sfr * disc_mtf(f, d_px[:, None])
            else:   # per colour: each observation's colours' blurs, mixed as its edge mixes them
                sfr = sfr * np.abs(np.einsum("nc,ncf->nf", self._mix, disc_otf(f[None], d_px[:, :, None])))
        if shifts_px is not None:
            sfr = sfr * colour_shift_mtf(self._mix, shifts_px, obs.normal_deg, obs.freq)
        if transfer is not None:
            sfr = sfr * transfer
        sfr = np.broadcast_to(sfr, (len(obs), f.shape[1])).copy()
        return Prediction(sfr @ self._area_w, sfr, obs.freq)

    def otf_along(self, xb, freq, normal_deg) -> np.ndarray:
        """(F,) signed OTF of the model's optics and pixel along one edge
        normal (no defocus): the transform of its line spread function."""
        f = np.abs(np.asarray(freq, float))
        sigma = float(xb[0])
        n = float(xb[1]) if len(xb) > 1 else self.f_number
        t = math.radians(float(normal_deg))
        a = self.aperture_px
        return (diffraction_mtf(f / (self.obs.sensor.pixel_pitch_um * 1e-3), self.wavelength_nm, n)
                * np.exp(-2 * np.pi ** 2 * sigma ** 2 * f ** 2) * np.sinc(a * f * math.cos(t)) * np.sinc(a * f * math.sin(t)))

    def measurement_bias(self, xb):
        """What the measurement adds: the model's own edge (its exact
        profile, :func:`edge_profile` of :meth:`otf_along`) rendered in each
        observation's ROI with its noise and measured (ISO 12233). Besides
        the noise's rise this holds what the LSF record window does to the
        diffraction PSF's far tails: light beyond the ROI is not seen, so the
        measured SFR sits ≈ 1 % above the exact MTF at low frequencies
        (f/2, 64-px ROI) — a Gaussian edge of the same SFRA has no such
        tails. Returns (sfra bias (N,), sfr bias (N, F), noise std (N, 1 + K):
        SFRA's and the SFR band means' (:data:`calibration.fit.forward_model.BANDS`))."""
        return _edge_bias(self.obs, lambda nu, normal: self.otf_along(xb, nu, normal))

    #: a diffraction × Gaussian × pixel-aperture LSF is symmetric: no asymmetry, none added by ISO
    odd_bias = 0.0

    def odd(self, xb, defocus_mm=None) -> np.ndarray:
        """(N, K) zeros: the parametric MTF's LSF is symmetric."""
        from calibration.sfr.asymmetry import BANDS as ODD_BANDS

        return np.zeros((len(self.obs), len(ODD_BANDS)))


def psf_map_window_um(sensor) -> float:
    """The PSF window, µm, that a PSF map takes by default on ``sensor``
    (:func:`calibration.optics.psf.map.default_psf_n` samples at half its
    pixel pitch): 32 µm, but at least 32 samples where those stay within
    48 µm, so 44.8 µm on 2.8 µm pixels and 32 µm on 1 µm ones.

    >>> from types import SimpleNamespace
    >>> psf_map_window_um(SimpleNamespace(pixel_pitch_um=2.8)), psf_map_window_um(SimpleNamespace(pixel_pitch_um=1.0))
    (44.8, 32.0)
    """
    from calibration.optics.psf.map import default_psf_n

    pitch = 0.5 * float(sensor.pixel_pitch_um)
    return default_psf_n(pitch) * pitch


def psf_map_model(sensor):
    """The forward model's settings (:class:`calibration.fit.forward_model.ModelSettings`)
    that sample the PSF as a PSF map does by default on ``sensor``, the map
    `isp calib simulate` renders a capture with: its window
    (:func:`psf_map_window_um`), its pupil grid and its wavelengths per
    channel (:class:`calibration.optics.psf.map.PSFMapSettings`). Through
    them a simulated device's true lens reproduces its capture within the
    noise of two captures at any pixel (docs/results/loop.md). Each
    difference shows: a window narrower than the capture's drops light the
    SFR's lowest band loses, a wider one keeps light the capture did not
    have (e9 at 2000 × 1500, 34 µm: 1.80 of the noise there; e1 at full
    size, 45 µm: 2.06); a coarser pupil grid misplaces the PSF's outer light
    (e2 at full size, 48 samples: 1.38 in that band, 64: 1.13); two
    wavelengths per channel instead of three miss some of its colour blur
    (the same device's SFRA: 1.25 against 1.08).

    >>> from types import SimpleNamespace
    >>> m = psf_map_model(SimpleNamespace(pixel_pitch_um=1.0))
    >>> m.window_um, m.pupil_samples, m.n_wavelengths
    (32.0, 64, 3)
    """
    from calibration.fit.forward_model import ModelSettings
    from calibration.optics.psf.map import PSFMapSettings
    from calibration.optics.psf.spectral import DEFAULT_WAVELENGTHS_PER_CHANNEL

    m = PSFMapSettings()
    return ModelSettings(window_um=psf_map_window_um(sensor), pupil_samples=m.pupil_samples,
                         n_wavelengths=m.n_wavelengths or DEFAULT_WAVELENGTHS_PER_CHANNEL)


#: the lens base's least PSF window, µm. A real PSF's outer light reaches past
#: the 32 µm a PSF map takes on fine pixels, and a model that drops it finds a
#: glare that is not there: on a perturbed e9 whose device PSFs span 48 µm
#: (``tests/calibration/loop/test_closure.py``, the field-curvature case) a
#: 32 µm base added veiling glare beside the curvature, a 45 µm one did not
BASE_MIN_WINDOW_UM = 45.0


def base_model(sensor):
    """The lens base's model settings on ``sensor``: :func:`psf_map_model`'s
    wavelengths, and its window and pupil grid or :data:`BASE_MIN_WINDOW_UM`
    with the pupil grid the fitter's model takes for it
    (:meth:`~calibration.fit.forward_model.ModelSettings.with_window`),
    whichever is the wider. On 2.8 µm pixels the window is the map's to
    within 0.2 µm; on 1 µm pixels the map's 32 µm window truncates the
    capture's PSF, which the base keeps to 45 µm
    (docs/results/loop.md: there the simulator, not the model, is the
    narrower).

    >>> from types import SimpleNamespace
    >>> m = base_model(SimpleNamespace(pixel_pitch_um=1.0))
    >>> m.window_um, m.pupil_samples, m.n_wavelengths
    (45.0, 68, 3)
    """
    import dataclasses

    from calibration.fit.forward_model import ModelSettings

    m = psf_map_model(sensor)
    if m.window_um >= BASE_MIN_WINDOW_UM:
        return m
    wide = ModelSettings().with_window(BASE_MIN_WINDOW_UM)
    return dataclasses.replace(m, window_um=wide.window_um, pupil_samples=max(m.pupil_samples, wide.pupil_samples))


#: the kinds of perturbation :class:`LensBase` fits by default, focus among them
#: (:func:`calibration.optics.perturb.default_names`). Why all of them: on e2's clean device
#: (``isp calib simulate US-12210142-B2-e2.zmx --perturb random --seed 5 --size 2000,1500``, the
#: coarse stage on 140–224 edges, the fit on all 1,200) the base over decenters, tilts and air gaps (47)
#: ended at χ² 55 per residual, over them with focus and the glasses' indices (56) at 23, over
#: every kind but focus (91) at 53, and over every kind and focus (92) at 14.2, where the
#: device's own lens scores 14.1 (χ² with the fitter's default σ of 0.002 cycles/pixel per
#: edge, about a quarter of this capture's noise)
BASE_KINDS = ALL_KINDS


#: the base fit's coarse stage also fits this many of its most sensitive assembly perturbations
#: (decenters, tilts, gaps, focus) first, then all of them, and keeps the better of that and all at
#: once (:class:`calibration.fit.proxy.ProxyFitSettings`'s ``stage_params``). Why: on the loop suite's
#: case 14 (``python -m benchmarks.loop_suite --only 14``: e9, every tolerance drawn, nothing put in; 92
#: perturbations, the coarse stage on 192 edges) all of them at once from the nominal lens ended at
#: merit 70.9 k, where the device's own lens scores 28.5 k, its four restarts' probes at 107–139 k, and
#: a Gaussian prior on the perturbations (σ 0.15 or 0.3 tolerance) at 60 k; 24 assembly perturbations
#: first, then all, ended at 26.4 k (12 first: 38.4 k; the 24 most sensitive of all 92 first: 39.4 k),
#: and the case at 1.07 × its noise floor instead of 1.77 ×. Staged alone, case 1 (e2, crosstalk put
#: in) ended at 2.30 × instead of 1.75 ×: neither start finds every device's basin
LOOP_STAGE_PARAMS = 24


#: iterations of the base fit's stage on all edges (:class:`calibration.fit.proxy.ProxyFitSettings`'s
#: ``fine_iter``): what the loop's ten minutes on two cores allow with every perturbation free
LOOP_FINE_ITER = 12


class LensBase:
    """A lens prescription and its perturbations (module docstring):
    ``names``, or every one of ``kinds`` (:data:`BASE_KINDS`). ``n_params``: the most
    sensitive of those fitted, or None for all of them. Why all by
    default: on e1's clean device, every tolerance drawn, ``isp calib fit
    --window-um 45`` over its 42 decenters, tilts, gaps and focus ended at
    SFRA RMS 0.0091 in 424 s, over the 24 most sensitive at 0.0104 in 632 s
    (more restarts), the noise floor being 0.0078."""

    refit_in_cv = False    # every evaluation traces the lens: candidates are fitted with it held

    def __init__(self, nominal, obs: Observations, *, settings=None, names=None, n_params: int | None = None,
                 kinds=BASE_KINDS):
        from calibration.optics.perturb import nominal as as_perturbed
        from calibration.fit.proxy import default_names, focus_name, parameter_bounds, parameter_space, screen_parameters
        from calibration.fit.forward_model import SfrModel

        self.model = SfrModel(nominal, obs, settings or base_model(obs.sensor))
        self.obs = obs
        self.nominal = nominal
        names = default_names(nominal, tuple(kinds)) if names is None else list(names)
        if n_params is not None and n_params < len(names):
            names = screen_parameters(self.model, names, n_params)
        self.space = parameter_space(nominal, names)
        self.names = tuple(self.space.names)
        k = len(self.names)
        self.x0 = np.zeros(k)
        self.lower, self.upper = parameter_bounds(self.names, focus_name(nominal))
        self.scale = np.full(k, 0.1)
        self.geometry = _geometry(obs, self.model.node_mm[:, 0], self.model.node_mm[:, 1], self.model.channels)
        self._pl = as_perturbed(nominal)
        self.description = f"lens {nominal.name or ''} with {k} perturbations (tolerance units)".replace("  ", " ")

    def lens(self, xb):
        return self.space.apply(np.asarray(xb, float) * self.space.tolerance)

    def defocus_um(self, xb) -> float:
        """On-axis defocus of the sensor, µm (+: beyond the lens's best
        focus, away from the lens), against the design's own focus offset
        (:func:`calibration.optics.spot.defocus`: RMS spot on axis, the
        criterion by which :func:`calibration.optics.spot.refocus` sets a
        drawn device). This, not the focus parameter (the last gap), is what
        the SFR fixes: the gap trades against every other tolerance that
        moves focus. Measured on the loop suite's cases 1 and 6 (e2, e9;
        every tolerance drawn, refocused, no focus shift put in): the fitted
        last gap lies 30 and 17 µm from the device's, the fitted defocus
        0.6 and 4.8 µm from the device's."""
        from calibration.optics.spot import best_focus, defocus

        if not hasattr(self, "_focus_nominal"):
            self._focus_nominal = best_focus(self.nominal)
        return 1e3 * defocus(self.lens(xb), self._focus_nominal)

    def defocus_map_um(self, xb, points_mm) -> np.ndarray:
        """:meth:`defocus_um` at image points (N, 2) mm
        (:func:`calibration.optics.spot.defocus_map`), µm; the design's
        reference there (:func:`~calibration.optics.spot.design_foci`) is
        kept for the next call at the same points."""
        from calibration.optics.spot import defocus_map, design_foci

        pts = np.asarray(points_mm, float).reshape(-1, 2)
        if getattr(self, "_foci_key", None) != pts.tobytes():
            self._foci, self._foci_key = design_foci(self.nominal, pts), pts.tobytes()
        return 1e3 * defocus_map(self.lens(xb), pts, self._foci)

    def with_settings(self, settings) -> LensBase:
        """The same base (lens, observations, parameters) evaluated by a
        model of other ``settings`` (e.g. the fitter's cheaper Jacobian
        model, :data:`calibration.fit.forward_model.FAST_JACOBIAN`); the
        measurement bias it holds is kept."""
        return _rebuilt_lens_base(self.nominal, self.obs, settings, self.names, getattr(self, "odd_bias", None))

    def __reduce__(self):
        # rebuilt where unpickled (a worker process): the model's caches are ~180 MB pickled on a
        # 1,200-edge capture, the model itself 0.1 s to build
        return _rebuilt_lens_base, (self.nominal, self.obs, self.model.settings, self.names,
                                    getattr(self, "odd_bias", None))

    def start(self, executor=None) -> np.ndarray:
        """Where the loop's base fit starts: :func:`calibration.fit.proxy.fit_proxy`
        over these parameters, on the fitter's residuals (SFRA, the SFR bands
        and the LSF asymmetry where measured), whose coarse stage and restarts find
        the basin. Why: from the nominal lens the loop's own DLS settled in a
        local minimum on a device perturbed in all 48 parameters (e9 dev3 of
        `isp calib simulate --perturb random --seed 3`, 24 parameters: SFRA
        RMS 0.0222, where ``fit_proxy`` with the same parameters reaches
        0.0133 and the device's own lens scores 0.0138). ``executor`` (an
        :class:`isp.runtime.executor.Executor`) runs the fit; default up
        to 2 worker processes, no progress bar."""
        from isp.runtime.executor import pool_executor

        from calibration.fit.proxy import ProxyFitSettings, fit_proxy, resolve_residuals
        from calibration.fit.forward_model import FAST_JACOBIAN

        settings = ProxyFitSettings(model=self.model.settings, residuals=resolve_residuals("auto", self.obs),
                                    jacobian_model=FAST_JACOBIAN, fine_iter=LOOP_FINE_ITER,
                                    stage_params=LOOP_STAGE_PARAMS)
        fit = fit_proxy(self.nominal, self.obs, settings, names=list(self.names),
                        executor=pool_executor(None) if executor is None else executor)
        return np.clip(fit.u, self.lower, self.upper)

    def predict(self, xb, *, defocus_mm=None, shifts_px=None, transfer=None) -> Prediction:
        return self.model.predict(self.lens(xb), defocus_mm=defocus_mm, shifts_px=shifts_px, transfer=transfer)

    def measurement_bias(self, xb):
        b = self.model.measurement_biases(self.lens(xb))
        self.odd_bias = b.odd
        return b.sfra, b.sfr, b.noise

    def odd(self, xb, defocus_mm=None) -> np.ndarray:
        """(N, K) noise-free LSF asymmetry (:mod:`calibration.sfr.asymmetry`)."""
        return self.model.predict_odd(self.lens(xb), defocus_mm)


def _rebuilt_lens_base(nominal, obs, settings, names, odd_bias) -> LensBase:
    base = LensBase(nominal, obs, settings=settings, names=names)
    if odd_bias is not None:
        base.odd_bias = odd_bias
    return base


def area_weights(freq, fmax: float = 0.5) -> np.ndarray:
    """(F,) weights w with ``sfr @ w`` = the SFRA, the trapezoid area under
    ``sfr`` from 0 to ``fmax`` with the end value interpolated — the same
    number as :func:`calibration.fit.forward_model.sfra_of`, in one product (NaN
    weights if ``freq`` stops short of ``fmax``).

    >>> f = np.array([0.0, 0.2, 0.4, 0.6])
    >>> bool(np.isclose(np.ones(4) @ area_weights(f), 0.5)), bool(np.isclose(f @ area_weights(f), 0.125))
    (True, True)
    """
    f = np.asarray(freq, float)
    w = np.zeros(len(f))
    if f[-1] < fmax:
        return np.full(len(f), np.nan)
    n = int(np.searchsorted(f, fmax, side="right"))
    for k in range(n - 1):                      # full trapezoids
        dw = 0.5 * (f[k + 1] - f[k])
        w[k] += dw
        w[k + 1] += dw
    if f[n - 1] < fmax:                         # the last piece up to fmax, its end interpolated
        j = n - 1
        t = (fmax - f[j]) / (f[j + 1] - f[j])
        dw = 0.5 * (fmax - f[j])
        w[j] += dw * (2.0 - t)
        w[j + 1] += dw * t
    return w


def edge_profile(otf, du: float = 1.0 / 16.0, half_px: float = 256.0):
    """(u px (M,), ESF (M,)) of a line spread function given by its real
    transform ``otf(nu)`` (cycles/pixel, 1 at 0): the LSF is sampled every
    ``du`` px over ±``half_px`` by an inverse FFT, the ESF is its running
    sum (0 → 1), at the bin edges u.

    >>> u, e = edge_profile(lambda nu: np.exp(-2 * np.pi ** 2 * nu ** 2))   # Gaussian, σ = 1 px
    >>> round(float(np.interp(0.0, u, e)), 6), round(float(np.interp(1.0, u, e)), 4)
    (0.5, 0.8413)
    """
    m = round(2 * half_px / du)
    nu = np.fft.rfftfreq(m, d=du)
    lsf = np.fft.fftshift(np.fft.irfft(np.asarray(otf(nu), float), n=m))      # masses, sum 1
    u = (np.arange(m) - m // 2 + 0.5) * du                                      # upper edge of each bin
    return u, np.cumsum(lsf)


def _edge_bias(obs: Observations, otf, default_roi=(64.0, 96.0)):
    """(sfra bias (N,), sfr bias (N, F), noise std (N, 1 + K) of SFRA and
    the SFR band means) per observation: the edge of
    transfer ``otf(nu, normal_deg)`` rendered (slanted as observed, in an ROI
    of the observation's size, ``default_roi`` (across, along) px where it
    has none) with the observation's noise and measured, minus the exact
    SFR ``|otf|``."""
    from calibration.sfr.esfr import SfrError

    rng = np.random.default_rng(0)
    n = len(obs)
    f = np.asarray(obs.freq, float)
    a_bias, sd, c_bias = np.zeros(n), np.zeros((n, 1 + len(BANDS))), np.zeros((n, len(f)))
    ext = _roi_extent(obs)
    cache = {}
    # at least 64 noisy renders in all (4 per edge where there are many): the noise floor of a
    # single edge split into four segments, from 4 renders each, was off by ±20 % (12 degrees of freedom)
    renders = int(min(32, max(4, math.ceil(64 / max(n, 1)))))
    for i in range(n):
        normal = float(obs.normal_deg[i])
        dev = (normal + 45.0) % 90.0 - 45.0                  # the edge's slant from the pixel axes
        angle = abs(dev) if abs(dev) >= 1.0 else 5.0
        across, along = default_roi if ext is None else (float(ext[0][i]), float(ext[1][i]))
        key = (round(normal, 3), angle, across, along)
        if key not in cache:
            u, esf = edge_profile(lambda nu, normal=normal: otf(nu, normal))
            h, w = int(along), int(across)
            t = math.radians(angle)
            xs = np.arange(w) - (w - 1) / 2.0
            ys = np.arange(h) - (h - 1) / 2.0
            d = math.cos(t) * xs[None, :] - math.sin(t) * ys[:, None]        # signed distance from the edge
            exact = np.abs(otf(f, normal))
            cache[key] = (np.interp(d, u, esf), exact, sfra_of(f, exact[None])[0])
        prof, exact, exact_a = cache[key]
        step = float(obs.step[i]) or 0.6
        noise = float(obs.noise[i])
        img = 0.2 + step * prof
        vals, curves = [], []
        measure = measure_like(obs, i)   # as it was measured: an image, or a mosaic's plane
        for _ in range(renders if noise > 0 else 1):
            try:
                r = measure(img + rng.normal(0, noise, img.shape) if noise > 0 else img)
            except SfrError:
                continue
            vals.append(r.sfra)
            curves.append(np.interp(f, r.freq, r.sfr, right=np.nan))
        if not vals:
            continue
        a_bias[i] = np.mean(vals) - exact_a
        c_bias[i] = np.nan_to_num(np.nanmean(curves, axis=0) - exact)
        if len(vals) > 1:
            with np.errstate(invalid="ignore"):
                sd[i] = np.nanstd(np.concatenate([np.array(vals)[:, None], band_means(f, np.array(curves))], axis=1),
                                  axis=0, ddof=1)
    return a_bias, c_bias, sd


def make_base(lens: str, obs, *, f_number="fit", n_params: int | None = None, pixel_um: float | None = None,
              kinds=BASE_KINDS):
    """The base model: ``"parametric"`` → :class:`ParametricBase` (F-number
    fitted from 2.0, or held at ``f_number``), else a lens file →
    :class:`LensBase` of the lens matched to the measurement's sensor
    (:func:`calibration.fit.measurements.match_sensor`; ``pixel_um`` its
    pitch, µm) over its perturbations of ``kinds`` (:data:`BASE_KINDS`). A bad lens file raises
    :class:`~calibration.optics.lens.LensError` naming it."""
    if lens == "parametric":
        if f_number in (None, "fit"):
            return ParametricBase(obs, f_number=2.0, fit_f_number=True)
        return ParametricBase(obs, f_number=float(f_number))
    from calibration.fit.measurements import match_sensor
    from calibration.optics.io import read_lens

    nominal = read_lens(lens)
    nominal, obs = match_sensor(nominal, obs, pixel_um=pixel_um)
    return LensBase(nominal, obs, n_params=n_params, kinds=kinds)
