"""Loop closure on synthetic devices with effects the base model lacks.

The devices are rendered edge by edge through PSFs built from the optics
(diffraction at f/2 × aberration blur × the device's defocus) and measured
with ISO 12233; effects of the measurement chain (sharpening, crosstalk) are
applied to the pixels — not through the model's own transfer terms.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import convolve, gaussian_filter

from calibration.effects import Effect, create_effect, list_effects, register_effect
from calibration.lens import Sensor
from calibration.loop import close_loop, write_report
from calibration.loop_base import ParametricBase, diffraction_mtf, disc_mtf
from calibration.proxy_synth import edge_sites, synthetic_observations

SENSOR = Sensor(pixel_pitch_um=1.0, width_px=4000, height_px=3000)
CX, CY = 1999.5, 1499.5


def _psf(dz_mm, sigma=0.6, n_f=2.0, n=64, q=0.25, extra=1.0):
    f = np.fft.fftfreq(n, d=q)
    fr = np.hypot(*np.meshgrid(f, f))
    otf = diffraction_mtf(fr / 1e-3, 550.0, n_f) * np.exp(-2 * np.pi ** 2 * sigma ** 2 * fr ** 2) * extra
    if dz_mm:
        otf = otf * disc_mtf(fr, abs(dz_mm) / n_f / 1e-3)
    p = np.maximum(np.fft.fftshift(np.real(np.fft.ifft2(otf))), 0)
    return p / p.sum()


class _Device:
    """A PSF-map stand-in: the device's PSF at each region centre."""

    def __init__(self, dz=lambda x, y: 0.0, sigma=lambda x, y: 0.6, grid=(5, 7)):
        self.sensor, self.grid, self.pitch_um = SENSOR, grid, 0.25
        self.sites = {(r, k): (x - CX, y - CY) for r, k, x, y in edge_sites(SENSOR, grid)}
        self.dz, self.sigma = dz, sigma

    def psf(self, r, k, ch):
        x, y = self.sites[(r, k)]
        return SimpleNamespace(data=_psf(self.dz(x, y), sigma=self.sigma(x, y)))


def _loop(device, ops=(), noise=0.003, effects=None):
    obs = synthetic_observations(device, noise=noise, image_ops=ops, rng=1)
    return close_loop(ParametricBase(obs, f_number=2.0), obs, effects=effects, progress=False), obs


def test_registry_lists_the_required_effects():
    have = set(list_effects())
    assert {"sensor_tilt", "focus_shift", "field_curvature", "pixel_crosstalk", "lateral_ca", "sharpening",
            "veiling_glare"} <= have
    with pytest.raises(KeyError, match="unknown effect"):
        create_effect("nope")


def test_clean_device_gets_no_spurious_effect():
    rep, _ = _loop(_Device())
    assert rep.effects_added == []
    assert rep.error_after["chi2_per_obs"] < 1.5 ** 2


def test_field_curvature_is_named_and_measured():
    rep, _ = _loop(_Device(dz=lambda x, y: 0.012 * (np.hypot(x, y) / 2500.0) ** 2))
    assert rep.effects_added[:1] == ["field_curvature"]
    assert rep.effect_values["field_curvature"]["dz_corner_um"] == pytest.approx(12.0, abs=2.0)
    assert rep.error_after["sfra_rms"] <= 1.5 * rep.noise_floor
    assert rep.error_before["sfra_rms"] > 10 * rep.noise_floor


def test_sensor_tilt_is_named():
    rep, _ = _loop(_Device(dz=lambda x, y: x * 1e-3 * np.tan(np.radians(0.4))))
    assert rep.effects_added[:1] == ["sensor_tilt"]
    # a tilt about the y axis: defocus grows along x
    assert rep.effect_values["sensor_tilt"]["tilt_y_deg"] == pytest.approx(0.4, abs=0.1)


def test_sharpening_in_the_chain_is_named_and_measured():
    rep, _ = _loop(_Device(), ops=[lambda img, x, y: img + 0.8 * (img - gaussian_filter(img, 1.2, mode="nearest"))])
    assert rep.effects_added == ["sharpening"]
    v = rep.effect_values["sharpening"]
    assert v["gain"] == pytest.approx(0.8, abs=0.2)
    assert v["sigma_px"] == pytest.approx(1.2, abs=0.3)
    assert rep.error_after["sfra_rms"] <= 1.5 * rep.noise_floor


def test_sharpening_and_field_curvature_together():
    rep, _ = _loop(_Device(dz=lambda x, y: 0.012 * (np.hypot(x, y) / 2500.0) ** 2),
                   ops=[lambda img, x, y: img + 0.8 * (img - gaussian_filter(img, 1.2, mode="nearest"))])
    assert set(rep.effects_added) == {"sharpening", "field_curvature"}
    assert rep.error_after["sfra_rms"] <= 1.5 * rep.noise_floor


def test_effect_outside_the_registry_is_reported_unexplained():
    """A smudge blurring one corner only: no registry effect has that shape."""
    def sigma(x, y):
        return 1.6 if (x > 1000 and y < -700) else 0.6

    rep, _ = _loop(_Device(sigma=sigma))
    assert rep.unexplained and "unexplained residual" in rep.unexplained[0]
    assert rep.error_after["sfra_rms"] > 1.5 * rep.noise_floor


def test_report_files(tmp_path):
    rep, obs = _loop(_Device(dz=lambda x, y: 0.012 * (np.hypot(x, y) / 2500.0) ** 2))
    paths = write_report(rep, obs, tmp_path)
    import json

    doc = json.loads(paths["json"].read_text())
    for key in ("effects_added", "error_before", "error_after", "noise_floor"):
        assert key in doc
    assert doc["error_after"]["sfra_rms"] < doc["error_before"]["sfra_rms"]
    assert "field_curvature" in paths["md"].read_text()


def test_plugin_effect_via_register():
    @register_effect
    class Nothing(Effect):
        """Does nothing."""

        name = "test_nothing"
        names, units, x0, lower, upper, scale = ("a",), ("—",), (0.0,), (-1.0,), (1.0,), (0.1,)

    from calibration import effects

    try:
        assert "test_nothing" in list_effects()
        assert create_effect("test_nothing").transfer([0.0], None) is None
    finally:
        effects._REGISTRY.pop("test_nothing", None)
