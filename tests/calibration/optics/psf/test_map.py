"""PSF maps (calibration/optics/psf/map.py): the sensor frame and regions,
the chief-ray inversion, the symmetry shortcut = the full computation =
single PSFs, the cache, the plot, the default window and the refused
window past the pupil's replica period.

Kinds: property, and analytic (the replica period). The e9 tests need
``../shared/data``.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import calibration.optics.psf as P
from calibration.optics import trace as tr
from calibration.optics.perturb import apply
from calibration.optics.psf import map as M
from isp.errors import ConfigError
from isp.runtime.executor import create_executor, pool_executor

pytestmark = pytest.mark.property


SMALL = {"grid": (3, 4), "channels": ("G", "R"), "n": 16, "pitch_um": 1.0, "pupil_samples": 24, "n_wavelengths": 1}
QUIET = pool_executor(None)         # psf_map's default workers, without the progress bar


def test_property_sensor_frame_and_regions(e9):
    """property: pixel ↔ image-plane mapping round trips; region centres
    are antisymmetric about the axis; +θy lands on larger rows (image +y is
    down the sensor array); region_of inverts the region bounds."""
    s = e9.sensor
    x, y = M.sensor_to_image([0, s.width_px - 1], [0, s.height_px - 1], s)
    assert np.allclose(x, [-0.5 * (s.width_px - 1) * 1e-3, 0.5 * (s.width_px - 1) * 1e-3])
    assert np.allclose(M.image_to_sensor(x, y, s), [[0, s.width_px - 1], [0, s.height_px - 1]])
    c = M.region_centers_mm(s, (15, 20))
    assert np.array_equal(c, -c[::-1, ::-1])
    f = M.chief_ray_fields(e9, c[[0, 14, 7], [0, 19, 10]])
    assert f[0, 0] < 0 and f[0, 1] < 0 and f[1, 0] > 0 and f[1, 1] > 0 and f[2, 1] == 0
    m = M.PSFMap(np.zeros((15, 20, 1, 3, 3)), 0.5, c, np.zeros((15, 20, 2)), ("G",), s)
    for r, col in [(0, 0), (7, 10), (14, 19), (3, 17)]:
        x0, x1, y0, y1 = m.region_bounds_px(r, col)
        assert m.region_of(x0, y0) == (r, col) and m.region_of(x1 - 1e-6, y1 - 1e-6) == (r, col)
        cx, cy = M.image_to_sensor(*c[r, col], s)
        assert m.region_of(cx, cy) == (r, col)


def test_property_chief_ray_inversion_lands_on_target(e9):
    """property: the real chief ray (real aiming) of the solved field lands
    on the requested image point within 1e-8 mm, corners included."""
    c = M.region_centers_mm(e9.sensor, (15, 20))
    pts = c[[0, 3, 7, 14], [0, 12, 10, 19]]
    fields = M.chief_ray_fields(e9, pts)
    for p, fld in zip(pts, fields):
        r = tr.pupil_rays(e9, tuple(fld), 1, e9.primary_nm, aiming="real", pupil=np.zeros((1, 2)))
        hit = tr.trace_to_image(e9, r, clip=False).position[0, :2]
        assert np.abs(hit - p).max() < 1e-8


def test_property_map_matches_single_psfs_and_symmetry_shortcut(e9, tmp_path):
    """property: the nominal map (symmetry shortcut: one quadrant mirrored)
    equals the full computation to float32 rounding, and each entry equals
    polychromatic_psf at the region's field and centre."""
    sym = M.psf_map(e9, M.PSFMapSettings(**SMALL), cache=False, executor=QUIET)
    full = M.psf_map(e9, M.PSFMapSettings(symmetry="none", **SMALL), cache=False, executor=QUIET)
    assert sym.psfs.dtype == np.float32 and sym.psfs.shape == (3, 4, 2, 16, 16)
    assert np.allclose(sym.psfs.sum(axis=(3, 4)), 1, atol=1e-6)
    assert np.abs(sym.psfs - full.psfs).max() < 1e-6 * full.psfs.max()
    assert np.allclose(sym.field_deg, full.field_deg, atol=1e-9)
    r, c = 0, 3
    one = P.polychromatic_psf(e9, tuple(sym.field_deg[r, c]), "R", method="debye", n_wavelengths=1,
                              pupil_samples=24, n=16, pitch_um=sym.pitch_um, center=tuple(sym.centers_mm[r, c]),
                              aim_each_wavelength=False)
    got = sym.psf(r, c, "R")
    assert np.abs(got.data - one.data).max() < 1e-6 * one.data.max()
    assert got.center_mm == tuple(sym.centers_mm[r, c])


def test_property_map_cache_and_files(e9, tmp_path):
    """property: a second call hits the cache and returns identical arrays;
    to_npz/from_npz round trips; the key changes with the perturbation and
    not with the lens's name, and a zero perturbation keeps it."""
    a = M.psf_map(e9, M.PSFMapSettings(**SMALL), cache_dir=tmp_path, executor=QUIET)
    files = list(tmp_path.glob("*.npz"))
    assert [f.name for f in files] == [f"{a.key}.npz"]
    mtime = files[0].stat().st_mtime_ns
    b = M.psf_map(e9, M.PSFMapSettings(**SMALL), cache_dir=tmp_path, executor=QUIET)
    assert np.array_equal(a.psfs, b.psfs) and b.key == a.key and files[0].stat().st_mtime_ns == mtime
    c = M.PSFMap.from_npz(M.PSFMap.to_npz(a, tmp_path / "x" / "map.npz"))
    assert np.array_equal(c.psfs, a.psfs) and c.sensor == a.sensor and c.channels == a.channels
    assert np.array_equal(c.channel_weights, a.channel_weights) and c.settings == a.settings
    st = a.settings
    k0 = M.cache_key(e9, st)
    assert k0 == a.key
    assert M.cache_key(apply(e9, {"e1.decenter_x": 0.0}), st) == k0
    assert M.cache_key(e9.replace(name="other", metadata={"path": "x"}), st) == k0
    assert M.cache_key(apply(e9, {"e1.decenter_x": 1e-4}), st) != k0
    assert M.cache_key(apply(e9, {"m2.nd": 1e-5}), st) != k0
    assert M.cache_key(e9, {**st, "n": 17}) != k0


def test_property_plot_psf_map(e9, tmp_path):
    """property: the mosaic is written."""
    m = M.psf_map(e9, M.PSFMapSettings(**SMALL), cache=False, executor=QUIET)
    out = M.plot_psf_map(m, tmp_path / "map.png", channel="G", scale="log")
    assert out.exists() and out.stat().st_size > 1000


@pytest.mark.slow
def test_property_full_map_of_a_perturbed_e9(e9):
    """property (slow): a 15 × 20 × 3 map of a perturbed e9 (no symmetry,
    2 worker processes) is normalised; element 1 decentred by its 5 µm
    tolerance blurs beyond a 16 µm window (32 samples: 71 % of the energy
    inside, measured) and the map says so
    with a warning."""
    with pytest.warns(UserWarning, match="increase n"):
        m = M.psf_map(apply(e9, {"e1.decenter_y": 0.005}), M.PSFMapSettings(n=32), cache=False,
                      executor=create_executor("processes", 2))
    assert m.psfs.shape == (15, 20, 3, 32, 32)
    assert np.allclose(m.psfs.sum(axis=(3, 4)), 1, atol=1e-5)
    assert 0.6 < m.window_energy.min() < 0.9 and m.window_energy.max() <= 1.0
    assert not np.allclose(m.psfs[7, 10], m.psfs[7, 10, :, ::-1, :], atol=1e-3)


def test_default_window_is_32_um_whatever_the_pixel(e9):
    """property: the default window is :data:`WINDOW_UM` (32 µm) wide, not a
    sample count: on e9's 1 µm pixels 64 samples at 0.5 µm, and there the
    same decentred element 1 keeps ≥ 90 % of every region's energy (0.933
    measured) where 32 samples keep 0.82 and warn; 2.8 µm pixels keep 32
    samples (45 µm)."""
    pl = apply(e9, {"e1.decenter_y": 0.005})
    kw = dict(grid=(3, 4), channels=("G",), n_wavelengths=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = M.psf_map(pl, M.PSFMapSettings(**kw), cache=False, executor=create_executor("serial"))
    assert m.psfs.shape[-2:] == (64, 64) and m.psfs.shape[-1] * m.pitch_um == pytest.approx(M.WINDOW_UM)
    assert m.window_energy.min() > M.WINDOW_ENERGY_WARN
    with pytest.warns(UserWarning, match="increase n"):
        narrow = M.psf_map(pl, M.PSFMapSettings(n=32, **kw), cache=False, executor=create_executor("serial"))
    assert narrow.window_energy.min() < m.window_energy.min() - 0.05
    assert M.default_psf_n(1.4) == 32 and M.default_psf_n(0.25) == 128


def test_a_map_window_past_the_pupil_replica_period_is_refused(e9):
    """analytic: 64 pupil samples across e9's pupil make the diffracted
    field periodic with period λ·N·64 ≈ 66 µm at G's shortest node (527 nm,
    N = 1.95); 64 samples of 1.4 µm (2.8 µm pixels: 90 µm, what `isp synth --psf-n 64`
    gave there) are refused with the pupil grid that would do; the default
    window on those pixels (32 samples, 45 µm) is not."""
    from calibration.optics.lens import Sensor

    sensor = Sensor(2.807, 2000, 1500)
    kw = dict(cache=False, executor=create_executor("serial"), sensor=sensor)
    small = dict(grid=(1, 1), channels=("G",), n_wavelengths=1)
    with pytest.raises(P.PSFError, match=r"replica period \(≈ 65.7 µm .* pupil_samples ≥ 88 "):
        M.psf_map(e9, M.PSFMapSettings(n=64, **small), **kw)
    assert M.psf_map(e9, M.PSFMapSettings(**small), **kw).psfs.shape[-1] == 32


def test_property_image_surface_is_the_lens_refocused_region_by_region(e9):
    """property: a map on a sensor surface ``image_dz_mm`` beyond the image
    plane equals, region by region, the map of the lens refocused by that
    region's Δz (its last gap lengthened: an independent route, which
    re-aims each region's chief ray on the new plane): the MTF moduli
    agree (a shift of the PSF in its window, the chief ray's ``Δz·tan θ``,
    is the one difference). A tilted surface breaks the quadrant symmetry
    and is computed whole; a defocus widens the PSF."""
    from calibration.fit.proxy import focus_name

    # 0.25 µm samples: the PSF's MTF is not aliased (its cutoff, 1/(λN) ≈ 0.97 cy/µm, is under 2 cy/µm);
    # a 24 µm window holds a PSF the chief ray's slope moves by Δz·tan θ ≈ 2 µm
    small = {**SMALL, "n": 96, "pitch_um": 0.25, "pupil_samples": 40, "channels": ("G",)}
    rows, cols = small["grid"]
    x = M.region_centers_mm(e9.sensor, (rows, cols))[..., 0]
    tilt = 0.004 * x / np.abs(x).max()               # ±4 µm across the sensor: a tilt about y
    tilted = M.psf_map(e9, M.PSFMapSettings(**small), image_dz_mm=tilt, cache=False, executor=QUIET)
    flat = M.psf_map(e9, M.PSFMapSettings(**small), cache=False, executor=QUIET)

    def mtf(p):
        return np.abs(np.fft.fft2(p))

    for r, c in ((0, 0), (2, 3), (1, 1)):
        dz = float(tilt[r, c])
        refocused = M.psf_map(apply(e9, {focus_name(e9): dz}), M.PSFMapSettings(**small), cache=False,
                              executor=QUIET)
        a, b = tilted.psfs[r, c, 0], refocused.psfs[r, c, 0]
        # measured 0.004, 0.002, 0.0002 (the window crops a PSF the refocused map centres)
        assert np.abs(mtf(a) - mtf(b)).max() < 0.006, (r, c)
        assert np.abs(mtf(a) - mtf(flat.psfs[r, c, 0])).max() > 0.05, (r, c)   # the defocus is seen: 0.08–0.12
    # left and right halves differ: no mirrored quadrant
    assert np.abs(mtf(tilted.psfs[1, 0, 0]) - mtf(tilted.psfs[1, 3, 0][:, ::-1])).max() > 0.05
    with pytest.raises(ConfigError, match="image_dz_mm"):
        M.psf_map(e9, M.PSFMapSettings(**small), image_dz_mm=np.zeros((2, 2)), cache=False, executor=QUIET)
