"""Loop closure on a real phone lens (property test, slow; issue 5,
deliverable 5).

The device is the e9 phone lens (US 12,210,142 B2, example 9) with two
element perturbations, on a curved sensor: each field region is imaged at
its own focus, Δz = 8 µm·(r/r_corner)². Its PSFs come from the full PSF-map
path (:func:`calibration.optics.psf.map.psf_map`: real chief-ray aiming, three
wavelengths, a 48 µm window, wider than the model's), one map per distinct Δz, and its edges are rendered and
measured with ISO 12233. The loop fits :class:`LensBase` (the lens with
four perturbations, the truth's two among them, and no focus) with the
real tracer and must name field curvature and end within 1.5× the noise
floor. About 2–4 minutes on two cores.
"""

import numpy as np
import pytest

from tests.helpers import data_file

DZ_CORNER_MM = 0.008
TRUTH = {"e1.decenter_x": 0.002, "e2.tilt_yz": 0.02}
BASE_NAMES = ["e1.decenter_x", "e2.tilt_yz", "e1.decenter_y", "e3.tilt_zx"]


class _CurvedSensor:
    """A PSF-map stand-in: region (r, k) takes its PSF from the map made at
    that region's focus."""

    def __init__(self, maps, dz_of):
        first = next(iter(maps.values()))
        self.sensor, self.grid, self.pitch_um = first.sensor, first.grid, first.pitch_um
        self.maps, self.dz_of = maps, dz_of

    def psf(self, r, k, ch):
        return self.maps[self.dz_of[(r, k)]].psf(r, k, ch)


@pytest.mark.slow
def test_field_curvature_on_a_perturbed_phone_lens():
    from calibration.optics.psf import map as M
    from calibration.optics.io.lens_json import read_lens
    from calibration.loop.closure import close_loop
    from calibration.loop.base import LensBase
    from calibration.optics.perturb import apply
    from calibration.fit.proxy import focus_name
    from calibration.fit.synthetic_devices import edge_sites, synthetic_observations

    lens = read_lens(data_file("lenses", "phone", "US-12210142-B2-e9.zmx"))
    grid = (3, 4)
    sen = lens.sensor
    half = 0.5 * np.hypot(sen.width_px, sen.height_px)
    cx, cy = (sen.width_px - 1) / 2.0, (sen.height_px - 1) / 2.0
    dz_of = {(r, k): round(DZ_CORNER_MM * (np.hypot(x - cx, y - cy) / half) ** 2, 9)
             for r, k, x, y in edge_sites(sen, grid)}
    maps = {dz: M.psf_map(apply(lens, {**TRUTH, focus_name(lens): dz}), grid=grid, channels=("G",), n=96,
                          pupil_samples=64, n_wavelengths=3, cache=False, progress=False)
            for dz in sorted(set(dz_of.values()))}
    obs = synthetic_observations(_CurvedSensor(maps, dz_of), noise=0.003, rng=1)

    base = LensBase(lens, obs, names=BASE_NAMES)
    rep = close_loop(base, obs, progress=False)

    assert rep.effects_added == ["field_curvature"]
    assert rep.effect_values["field_curvature"]["dz_corner_um"] == pytest.approx(1e3 * DZ_CORNER_MM, abs=1.5)
    assert rep.error_after["sfra_rms"] <= 1.5 * rep.noise_floor
    assert rep.error_after["chi2_per_obs"] <= 1.5 ** 2
    assert rep.error_before["sfra_rms"] > 5 * rep.noise_floor     # the curvature was there to find
    # the lens perturbations the base holds are found too (within a quarter of their tolerance)
    fitted = dict(zip(rep.base_names, rep.base_x))
    for name in BASE_NAMES:
        assert fitted[name] == pytest.approx(TRUTH.get(name, 0.0) / base.space.tolerance[BASE_NAMES.index(name)],
                                             abs=0.25), name
