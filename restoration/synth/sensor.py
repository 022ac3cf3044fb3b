"""The sensor and the pipeline before the slot, for data synthesis: Bayer
sampling, Poisson–Gaussian noise from a DNG NoiseProfile, quantisation,
then the pipeline's own black level, white balance and demosaic, so the
synthesised input is exactly what the pipeline hands to the correction
slot (paper, section 4.1; the model "takes degraded raw-like data as
input").

Forward model of one crop (``x`` the blurred, *unbalanced* camera RGB on
the 0..1 scale of the NoiseProfile):

.. math::

    m = \\mathrm{CFA}(x),\\quad
    \\mathrm{DN} = Q\\big(S\\,\\mathcal{P}(m/S) + \\mathcal{N}(0, O)\\big),\\quad
    J = \\mathrm{demosaic}\\big(\\mathrm{WB}_{1/n}(\\mathrm{BL}(\\mathrm{DN}))\\big)

with ``(S, O)`` the NoiseProfile (variance ``S·m + O``;
:func:`calibration.simulate.sensor.add_noise`), ``Q`` the quantisation to the
camera's black and white levels (:func:`calibration.simulate.sensor.quantise`; the
sensor saturates at white), ``BL`` the black-level stage
(:func:`modules.black_level.subtract_black_level`), ``WB`` the
white-balance stage's per-site gains ``1/n``
(:func:`modules.white_balance.apply_white_balance`) and the demosaic
stage's method (:func:`modules.demosaic.demosaic`, ``malvar2004`` by
default). Lens shading is not simulated (the relative illumination and its
gain-map correction cancel in the signal; the noise amplification towards
the corners they cause is left out).

The NoiseProfile is scaled per pair by an ISO-like factor ``k``
(``S → kS``, ``O → k²O``: shot noise scales with the analog gain, read
noise with its square).
"""

from __future__ import annotations

import math

import numpy as np

from isp.frame import CFA

__all__ = ["capture_mosaic", "develop", "noise_profile_of", "sensor_model"]

#: NoiseProfile used when the sensor camera's file has none ((S, O) of
#: :class:`calibration.simulate.sensor.SensorModel`)
DEFAULT_NOISE_PROFILE = (2e-4, 2e-6)


def noise_profile_of(meta) -> tuple[float, float] | None:
    """(S, O) of a CameraMeta's NoiseProfile (mean over its planes), or None."""
    prof = getattr(meta, "noise_profile", None)
    if not prof:
        return None
    a = np.asarray(prof, dtype=np.float64).reshape(-1, 2)
    return float(a[:, 0].mean()), float(a[:, 1].mean())


def sensor_model(meta, sensor, noise_profile: tuple[float, float]):
    """A :class:`calibration.simulate.sensor.SensorModel` with the lens's sensor
    geometry and the camera's CFA, levels and the given NoiseProfile.

    Parameters
    ----------
    meta : CameraMeta
        The sensor camera (CFA, BlackLevel, WhiteLevel).
    sensor : calibration.optics.lens.Sensor
        Pixel pitch and size (the PSF map's).
    noise_profile : (S, O)
    """
    from calibration.simulate.sensor import SensorModel

    white = float(np.asarray(meta.white_level, dtype=np.float64).ravel()[0])
    black = float(np.asarray(meta.black_level, dtype=np.float64).mean())
    bits = min(16, max(8, math.ceil(math.log2(white + 1.0))))
    return SensorModel.from_sensor(sensor, cfa=meta.cfa or CFA.RGGB, bit_depth=bits, black_level=black,
                                   white_level=white, noise_profile=tuple(noise_profile))


def capture_mosaic(rgb: np.ndarray, sensor, origin: tuple[int, int], rng, *, noise: bool = True,
                   quantise: bool = True) -> np.ndarray:
    """The black-level-subtracted mosaic (0..1) a sensor records from
    unbalanced camera RGB.

    Parameters
    ----------
    rgb : (h, w, 3) ndarray
        Unbalanced camera RGB on the 0..1 scale.
    sensor : SensorModel
    origin : (row, col)
        Sensor pixel of ``rgb[0, 0]`` (sets the CFA phase).
    rng : numpy Generator
    noise, quantise : bool
        Without either the result is the CFA sampling of ``rgb`` exactly.

    Returns
    -------
    (h, w) ndarray, float32: what the black-level stage outputs.
    """
    from calibration.simulate.sensor import add_noise, mosaic
    from calibration.simulate.sensor import quantise as to_dn
    from modules.black_level import subtract_black_level

    m = mosaic(np.asarray(rgb, dtype=np.float64), sensor.cfa, origin=origin)
    if noise:
        step = 1.0 / sensor.dn_range if quantise else 0.0
        m = add_noise(m, sensor.noise_profile, rng, quantisation_step=step)
    if not quantise:
        return m.astype(np.float32)
    dn = to_dn(m, sensor).astype(np.float32)
    return subtract_black_level(dn, np.full((1, 1, 1), sensor.black_level), sensor.white_level)


def develop(mosaic: np.ndarray, cfa: CFA, neutral, method: str = "malvar2004") -> np.ndarray:
    """The pipeline's white balance and demosaic of a black-level-subtracted
    mosaic: camera RGB as the correction slot receives it.

    Parameters
    ----------
    mosaic : (h, w) ndarray, float32
    cfa : CFA
        Pattern at ``mosaic[0, 0]``.
    neutral : (3,) array_like
        Camera neutral; the gains are ``1 / neutral``.
    method : str
        A :data:`modules.demosaic.METHODS` name.

    Returns
    -------
    (h, w, 3) ndarray, float32.
    """
    from modules.demosaic import demosaic
    from modules.white_balance import apply_white_balance

    cfa = CFA.parse(cfa)
    bal = apply_white_balance(np.asarray(mosaic, dtype=np.float32), 1.0 / np.asarray(neutral, dtype=np.float64),
                              cfa.pattern)
    return demosaic(bal, cfa, method)
