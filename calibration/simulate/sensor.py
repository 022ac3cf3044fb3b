"""The image sensor of a simulated capture: CFA sampling, Poisson–Gaussian
noise and quantisation (the last three steps of the paper's eq. 14).

A :class:`SensorModel` holds what turns the optical image on the sensor
into the numbers a raw file stores: pixel pitch and size, the colour filter
array, the fill factor of the pixel aperture, black and white levels, bit
depth and the noise profile. Spectral responses are *not* here: the PSF map
carries one PSF per colour channel (eq. 14 integrates ``C_e(λ)·I(λ)`` into
it), and scene values are given per camera channel.

Forward model
-------------
For a pixel whose noise-free signal is ``x`` (linear, 0 = black, 1 = white,
after the optics, the pixel aperture, the CFA and relative illumination):

.. math::

    \\tilde x = S\\,\\mathcal{P}(x / S) + \\mathcal{N}(0,\\ O - \\Delta^2/12),
    \\qquad
    \\mathrm{DN} = \\operatorname{clip}\\big(\\operatorname{round}(B + \\tilde x\\,(W - B)),\\ 0,\\ W\\big)

with ``𝒫`` a Poisson variate (``x/S`` mean photo-electrons: ``1/S`` electrons
reach white), ``(S, O)`` the DNG NoiseProfile, ``B``/``W`` the black and white
levels and ``Δ = 1/(W − B)`` one DN in 0..1 units. The Gaussian part is
reduced by the quantisation variance ``Δ²/12`` (Sheppard's correction), so
the *stored* data has the variance the NoiseProfile promises,
``Var = S·x + O`` (DNG 1.7.1.0, tag NoiseProfile: "the noise variance
as a function of signal level, N(x) = sqrt(S·x + O)" on data scaled to
0..1), as long as the read noise is at least about half a DN
(``O ≳ Δ²/4``); below that the quantisation step itself is the floor.
Values above white clip at ``W`` (the sensor saturates); below black they
are kept down to 0 DN, as real sensors store them.

Units
-----
=================  ====================================================
quantity           unit, range
=================  ====================================================
``pixel_pitch_um`` µm, > 0
``black_level``    DN, 0 ≤ B < W
``white_level``    DN, ≤ 2**bit_depth − 1
``noise_profile``  (S, O) on 0..1 data: variance = S·x + O; S, O ≥ 0
``fill_factor``    area of the square pixel aperture / pitch², (0, 1]
signals ``x``      linear, 0 = black, 1 = white (float64)
raw ``DN``         uint16 sensor codes
=================  ====================================================

References
----------
Adobe, *Digital Negative (DNG) Specification* 1.7.1.0 (2023), tag
NoiseProfile (51041). A. Foi, M. Trimeche, V. Katkovnik, K. Egiazarian,
"Practical Poissonian-Gaussian noise modeling and fitting for single-image
raw-data", IEEE Trans. Image Process. 17(10), 1737–1754 (2008) — the
heteroscedastic model ``σ²(x) = a·x + b`` the DNG profile encodes.
EMVA Standard 1288, release 4.0 (2021), §2 (photon transfer: variance of
the digital signal = K·μ + σ_d² + σ_q², quantisation σ_q² = 1/12 DN²).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from isp.frame import CFA

from calibration.optics.lens import LensError, Sensor

__all__ = [
    "SensorError",
    "SensorModel",
    "add_noise",
    "as_rng",
    "dn_to_linear",
    "expose",
    "mosaic",
    "quantise",
]


class SensorError(LensError):
    """Invalid sensor settings; the message names the setting and its value."""


def as_rng(rng) -> np.random.Generator:
    """A numpy Generator from ``rng``: a Generator (used as is), an int seed,
    or None (seed 0: results are reproducible unless a generator is given)."""
    if isinstance(rng, np.random.Generator):
        return rng
    return np.random.default_rng(0 if rng is None else rng)


@dataclass(frozen=True)
class SensorModel:
    """What turns irradiance on the sensor into raw DN.

    Attributes
    ----------
    pixel_pitch_um : float
        Pixel pitch, µm.
    width_px, height_px : int
        Active area in pixels.
    cfa : isp.frame.CFA
        Pattern of the top-left 2×2 block (a name like ``"RGGB"`` is accepted).
    bit_depth : int
        Bits per stored sample, 8–16.
    black_level : float
        DN of zero signal.
    white_level : float, optional
        DN of saturation (signal 1); default ``2**bit_depth − 1``.
    noise_profile : (S, O)
        DNG NoiseProfile on 0..1 data: variance ``S·x + O``. ``1/S`` is the
        number of photo-electrons at white (:attr:`electrons_at_white`).
    fill_factor : float
        Light-sensitive fraction of the pixel area, a centred square
        aperture of side ``sqrt(fill_factor)`` pitches; 1 = the whole pixel
        (microlenses), the default.

    Examples
    --------
    >>> s = SensorModel(width_px=400, height_px=300)
    >>> s.white_level, s.cfa.value, round(s.electrons_at_white)
    (1023.0, 'RGGB', 5000)
    >>> [float(f"{v:.4g}") for v in SensorModel.from_electrons(6000, 2.5).noise_profile]
    [0.0001667, 1.736e-07]
    """

    pixel_pitch_um: float = 1.0
    width_px: int = 4000
    height_px: int = 3000
    cfa: CFA = CFA.RGGB
    bit_depth: int = 10
    black_level: float = 64.0
    white_level: float | None = None
    noise_profile: tuple[float, float] = (2e-4, 2e-6)
    fill_factor: float = 1.0

    def __post_init__(self):
        try:
            object.__setattr__(self, "cfa", CFA.parse(self.cfa))
        except ValueError as e:
            raise SensorError(str(e)) from None
        if not (isinstance(self.bit_depth, (int, np.integer)) and 8 <= self.bit_depth <= 16):
            raise SensorError(f"bit_depth must be an integer 8..16, got {self.bit_depth!r}")
        top = float(2 ** int(self.bit_depth) - 1)
        white = top if self.white_level is None else float(self.white_level)
        object.__setattr__(self, "white_level", white)
        if not (math.isfinite(self.pixel_pitch_um) and self.pixel_pitch_um > 0):
            raise SensorError(f"pixel_pitch_um must be > 0, got {self.pixel_pitch_um!r}")
        if int(self.width_px) < 2 or int(self.height_px) < 2:
            raise SensorError(f"sensor must be at least 2x2 pixels, got {self.width_px}x{self.height_px}")
        object.__setattr__(self, "width_px", int(self.width_px))
        object.__setattr__(self, "height_px", int(self.height_px))
        b = float(self.black_level)
        object.__setattr__(self, "black_level", b)
        if not (0.0 <= b < white <= top):
            raise SensorError(f"need 0 <= black_level < white_level <= {top:g} for {self.bit_depth} bits, "
                              f"got black {b:g}, white {white:g}")
        s, o = (float(v) for v in self.noise_profile)
        if not (math.isfinite(s) and math.isfinite(o) and s >= 0 and o >= 0):
            raise SensorError(f"noise_profile (S, O) must be finite and >= 0, got {self.noise_profile!r}")
        object.__setattr__(self, "noise_profile", (s, o))
        if not (0.0 < float(self.fill_factor) <= 1.0):
            raise SensorError(f"fill_factor must be in (0, 1], got {self.fill_factor!r}")

    # -- constructors ------------------------------------------------------
    @classmethod
    def from_sensor(cls, sensor: Sensor, **settings) -> SensorModel:
        """A model with the pitch and size of a lens file's
        :class:`~calibration.optics.lens.Sensor` and ``settings`` for the rest."""
        return cls(pixel_pitch_um=sensor.pixel_pitch_um, width_px=sensor.width_px,
                   height_px=sensor.height_px, **settings)

    @classmethod
    def from_electrons(cls, full_well_e: float, read_noise_e: float, gain: float = 1.0,
                       **settings) -> SensorModel:
        """A model whose NoiseProfile follows from the photo-electron scale.

        Parameters
        ----------
        full_well_e : float
            Electrons that reach the white level at unity gain, > 0.
        read_noise_e : float
            Input-referred read noise, electrons rms, >= 0.
        gain : float
            Analog gain (ISO / base ISO), >= 1: white is then reached at
            ``full_well_e / gain`` electrons.

        Notes
        -----
        ``S = gain / full_well_e`` (the value of one electron on the 0..1
        scale) and ``O = (read_noise_e · S)²``.
        """
        if not (full_well_e > 0 and read_noise_e >= 0 and gain > 0):
            raise SensorError(f"need full_well_e > 0, read_noise_e >= 0, gain > 0; got "
                              f"{full_well_e!r}, {read_noise_e!r}, {gain!r}")
        s = float(gain) / float(full_well_e)
        return cls(noise_profile=(s, (float(read_noise_e) * s) ** 2), **settings)

    def replace(self, **changes) -> SensorModel:
        return dataclasses.replace(self, **changes)

    # -- derived -----------------------------------------------------------
    @property
    def geometry(self) -> Sensor:
        """The pitch and size as a :class:`calibration.optics.lens.Sensor`."""
        return Sensor(pixel_pitch_um=self.pixel_pitch_um, width_px=self.width_px, height_px=self.height_px)

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return (self.height_px, self.width_px)

    @property
    def electrons_at_white(self) -> float:
        """Photo-electrons at signal 1 (``1/S``; inf without shot noise)."""
        s = self.noise_profile[0]
        return math.inf if s == 0 else 1.0 / s

    @property
    def dn_range(self) -> float:
        """``W − B``: DN per unit signal."""
        return self.white_level - self.black_level

    @property
    def aperture_px(self) -> float:
        """Side of the square pixel aperture in pixels, ``sqrt(fill_factor)``."""
        return math.sqrt(self.fill_factor)


def mosaic(rgb: np.ndarray, cfa, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Bayer sampling: each site keeps the channel its filter passes.

    Parameters
    ----------
    rgb : (H, W, 3) ndarray
        Per-channel signal, channels 0 R, 1 G, 2 B.
    cfa : isp.frame.CFA or str
        Pattern of the *sensor's* top-left 2×2 block.
    origin : (row, col)
        Position of ``rgb[0, 0]`` on the sensor (an odd offset changes the
        phase).

    Returns
    -------
    (H, W) ndarray, the dtype of ``rgb``.

    Examples
    --------
    >>> rgb = np.stack([np.full((2, 2), v) for v in (1.0, 2.0, 3.0)], axis=-1)
    >>> mosaic(rgb, "GRBG").tolist()
    [[2.0, 1.0], [3.0, 2.0]]
    >>> mosaic(rgb, "GRBG", origin=(0, 1)).tolist()
    [[1.0, 2.0], [2.0, 3.0]]
    """
    a = np.asarray(rgb)
    if a.ndim != 3 or a.shape[2] != 3:
        raise SensorError(f"rgb must be (H, W, 3), got shape {a.shape}")
    pat = CFA.parse(cfa).shifted(*origin).pattern
    out = np.empty(a.shape[:2], dtype=a.dtype)
    for i in range(2):
        for j in range(2):
            out[i::2, j::2] = a[i::2, j::2, pat[i, j]]
    return out


def cfa_channels(shape: tuple[int, int], cfa, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """(H, W) int8 channel index (0 R, 1 G, 2 B) of each site."""
    pat = CFA.parse(cfa).shifted(*origin).pattern.astype(np.int8)
    h, w = shape
    return np.tile(pat, ((h + 1) // 2, (w + 1) // 2))[:h, :w]


def add_noise(signal: np.ndarray, noise_profile: tuple[float, float], rng=None, *,
              quantisation_step: float = 0.0) -> np.ndarray:
    """Poisson–Gaussian noise with variance ``S·x + O`` (see the module notes).

    Parameters
    ----------
    signal : ndarray
        Noise-free signal ``x`` on the 0..1 scale (negative values are
        treated as 0 for the shot noise).
    noise_profile : (S, O)
    rng : numpy Generator, int or None
        See :func:`as_rng`.
    quantisation_step : float
        ``Δ``, one DN in 0..1 units, when the result will be quantised:
        ``Δ²/12`` is taken off the Gaussian variance (never below 0).

    Returns
    -------
    ndarray of float64, the shape of ``signal``.

    Examples
    --------
    >>> x = np.full(200_000, 0.25)
    >>> y = add_noise(x, (1e-3, 1e-5), rng=1)
    >>> round(float(y.mean()), 3), round(float(y.var()) / (1e-3 * 0.25 + 1e-5), 2)
    (0.25, 1.0)
    """
    gen = as_rng(rng)
    x = np.asarray(signal, dtype=np.float64)
    s, o = (float(v) for v in noise_profile)
    if s > 0:
        lam = np.maximum(x, 0.0) / s
        out = gen.poisson(lam).astype(np.float64)
        out *= s
    else:
        out = np.maximum(x, 0.0).copy()
    var_g = max(o - quantisation_step ** 2 / 12.0, 0.0)
    if var_g > 0:
        out += gen.standard_normal(x.shape) * math.sqrt(var_g)
    return out


def quantise(signal: np.ndarray, sensor: SensorModel) -> np.ndarray:
    """Store a 0..1 signal as DN: ``round(B + x·(W − B))`` clipped to
    ``[0, W]``.

    Returns
    -------
    ndarray of uint16.

    >>> quantise(np.array([-1.0, 0.0, 0.5, 1.0, 2.0]), SensorModel(width_px=2, height_px=2)).tolist()
    [0, 64, 544, 1023, 1023]
    """
    x = np.asarray(signal, dtype=np.float64)
    dn = np.rint(sensor.black_level + x * sensor.dn_range)
    np.clip(dn, 0.0, sensor.white_level, out=dn)
    return dn.astype(np.uint16)


def expose(signal: np.ndarray, sensor: SensorModel, rng=None, *, noise: bool = True) -> np.ndarray:
    """Noise and quantisation of a noise-free mosaic (0..1) into raw DN
    (uint16), as :func:`add_noise` then :func:`quantise`."""
    x = np.asarray(signal, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise SensorError("signal has NaN or inf values")
    if noise:
        x = add_noise(x, sensor.noise_profile, rng, quantisation_step=1.0 / sensor.dn_range)
    return quantise(x, sensor)


def dn_to_linear(dn: np.ndarray, sensor: SensorModel) -> np.ndarray:
    """``(DN − B)/(W − B)`` as float64: the 0..1 scale of the NoiseProfile."""
    return (np.asarray(dn, dtype=np.float64) - sensor.black_level) / sensor.dn_range
