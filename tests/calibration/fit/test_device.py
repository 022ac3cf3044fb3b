"""Device calibration files and their descriptor (kind: property).

The descriptor's PCA is checked on PSFs built from known directions (it
must find their span, with unit-spread coefficients); pixel integration
against the exact integral of a Gaussian over the pixel cells; the file
round-trips, stays under 64 KB, and refuses what is not its own; the
command line learns a basis and ``isp calib fit --basis`` writes the
device's file."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from calibration.fit.device import (MAX_BYTES, DescriptorBasis, DeviceCalibration, basis_from_psfs,
                                    check_calibration, design_key, pixel_psfs)
from calibration.optics.lens import Sensor
from calibration.optics.psf.map import PSFMap
from isp.cli.main import main
from isp.errors import InputError

pytestmark = pytest.mark.property


def _gaussian_map(sigma_px: float, n: int = 32, pitch: float = 0.5) -> PSFMap:
    x = (np.arange(n) - n // 2) * pitch           # µm, centre sample at n // 2 (1 µm pixels)
    g = np.exp(-0.5 * (x / sigma_px) ** 2)
    psf = np.outer(g, g)
    psf /= psf.sum()
    return PSFMap(psf[None, None, None], pitch, np.zeros((1, 1, 2)), np.zeros((1, 1, 2)), ("G",),
                  Sensor(1.0, 10, 10))


def test_pixel_psfs_integrate_over_the_pixel_cells():
    # a Gaussian sampled at half a pixel, summed 2 × 2: the composite midpoint rule's integral over
    # each 1-px cell; against the exact erf integral its error is h²/24 · f''/f per axis at the peak
    # (h = 0.5 px: 0.46 % per axis at σ = 1.5 px), falling as 1/σ²
    def error(sigma, n):
        p = pixel_psfs(_gaussian_map(sigma, n=n))[0, 0, 0]
        m = n // 2
        assert p.shape == (m, m) and p.sum() == pytest.approx(1.0, abs=1e-6)   # float32 samples
        edges = (np.arange(m + 1) - m // 2) - 0.25   # cell k covers samples 2k, 2k+1: [-0.25, 0.75) px about k
        cdf = np.array([0.5 * (1 + math.erf(e / (sigma * math.sqrt(2)))) for e in edges])
        exact = np.outer(np.diff(cdf), np.diff(cdf))
        exact /= exact.sum()
        return np.max(np.abs(p - exact)) / exact.max()

    e1, e2 = error(1.5, 32), error(3.0, 64)
    predicted = 2 * 0.5 ** 2 / 24 / 1.5 ** 2
    assert e1 == pytest.approx(predicted, rel=0.25)
    assert 0.2 < e2 / e1 < 0.3


def test_a_pitch_that_does_not_divide_the_pixel_is_refused():
    m = _gaussian_map(1.0, n=30, pitch=0.4)
    with pytest.raises(ValueError, match="does not divide"):
        pixel_psfs(m)


@pytest.fixture(scope="module")
def known_stack():
    """PSF maps ``mean + Σ a_i B_i`` over three orthogonal directions of known spread."""
    rng = np.random.default_rng(3)
    shape = (2, 3, 3, 6, 6)
    d = int(np.prod(shape[2:]))
    q, _ = np.linalg.qr(rng.normal(size=(d, 3)))
    mean = rng.random(shape)
    spread = np.array([3.0, 2.0, 0.5])
    a = rng.normal(size=(400, shape[0], shape[1], 3)) * spread
    stack = mean + (a @ q.T).reshape(400, *shape)
    return stack, q.T, spread


def test_the_basis_finds_the_span_and_its_spreads(known_stack):
    stack, directions, spread = known_stack
    b = basis_from_psfs(stack, lens="x", design="d", grid=(2, 3), channels=("R", "G", "B"), components=5)
    # three directions hold all the variance; in every region the first three components span them
    # (to the half precision the file stores components in)
    assert b.explained[2] == pytest.approx(1.0, abs=1e-4)
    for r in range(2):
        for c in range(3):
            proj = b.components[r, c, :3] @ directions.T
            assert np.allclose(np.linalg.svd(proj, compute_uv=False), 1.0, atol=1e-3)
    # aligned: a component is the same direction, with the same sign, in every region (what makes
    # interpolating the descriptor between regions meaningful); a region's own PCA fixes no sign
    first = b.components[0, 0, :3]
    for r in range(2):
        for c in range(3):
            assert np.all(np.einsum("kd,kd->k", b.components[r, c, :3], first) > 0.99)
    # the scales are the coefficients' spread, so the descriptor has unit spread over the draws
    assert np.sort(b.scales[..., :3], axis=-1)[..., ::-1] == pytest.approx(np.broadcast_to(spread, (2, 3, 3)),
                                                                           rel=0.12)
    d = np.stack([b.project(s, 3) for s in stack])
    assert d.std(axis=0) == pytest.approx(1.0, rel=1e-9)
    # in the span, reconstruction is exact to the components' half precision
    assert np.abs(b.reconstruct(b.project(stack[7], 3)) - stack[7]).max() < 2e-3 * np.abs(stack[7] - b.mean).max()


def test_basis_and_device_files_round_trip(tmp_path, known_stack):
    stack = known_stack[0]
    b = basis_from_psfs(stack, lens="x", design="d", grid=(2, 3), channels=("R", "G", "B"), components=3,
                        sensor=Sensor(1.0, 60, 40))
    b2 = DescriptorBasis.load(b.save(tmp_path / "b.npz"))
    assert b2.key == b.key and b2.sensor == b.sensor and b2.draws == 400
    d = b.project(stack[0], 3)
    cal = DeviceCalibration("x", "d", b.key, d, fit={"sfra_rms_after": 0.0061},
                            source={"measured": "c.dng"})
    back = DeviceCalibration.load(cal.save(tmp_path / "device.json"))
    check_calibration(back, b2)
    # four significant digits of unit-spread numbers
    assert np.max(np.abs(back.descriptor - d) / np.maximum(np.abs(d), 1e-3)) < 6e-4
    assert back.fit == {"sfra_rms_after": 0.0061} and json.loads((tmp_path / "device.json").read_text())[
        "format"] == "device/v1"
    # another design's or another basis's file is refused, in one line
    with pytest.raises(ValueError, match="another lens design"):
        check_calibration(DeviceCalibration("y", "e", b.key, d), b2)
    with pytest.raises(ValueError, match="another basis"):
        check_calibration(DeviceCalibration("x", "d", "f" * 64, d), b2)


def test_a_file_over_64_kb_is_neither_written_nor_read(tmp_path):
    big = DeviceCalibration("x", "d", "k", np.ones((30, 40, 32)))
    with pytest.raises(ValueError, match="exceeds"):
        big.save(tmp_path / "big.json")
    assert not (tmp_path / "big.json").exists()
    p = tmp_path / "huge.json"
    p.write_text(" " * (MAX_BYTES + 1))
    with pytest.raises(InputError, match="huge.json.*at most"):
        DeviceCalibration.load(p)


@pytest.mark.parametrize("text, why", [("{", "not JSON"), ('{"format": "lens/v1"}', "not a device/v1"),
                                       ('{"format": "device/v1"}', "without"),
                                       ('{"format": "device/v1", "lens": "x", "design": "d", "basis": "k", '
                                        '"grid": [1, 2], "components": 1, "descriptor": [[[1.0]]]}', "shape")])
def test_a_bad_device_file_is_one_line_naming_it(tmp_path, text, why):
    p = tmp_path / "dev.json"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        DeviceCalibration.load(p)
    assert "dev.json" in str(e.value) and why in str(e.value) and "\n" not in str(e.value)


def test_the_design_key_ignores_perturbation_name_and_sensor(e9_lens, e9_zmx):
    from calibration.fit.proxy import parameter_space
    from calibration.optics.io import read_lens

    space = parameter_space(e9_lens, ["s1.thickness"])
    k = design_key(e9_lens)
    assert design_key(space.apply(space.tolerance)) == k
    assert design_key(e9_lens.replace(sensor=Sensor(2.8, 2000, 1500))) == k
    e1 = read_lens(e9_zmx.parent / "US-11906710-B2-e1.zmx")
    assert design_key(e1) != k


def test_calib_basis_then_fit_writes_the_device_file(capsys, tmp_path, e9_zmx):
    from calibration.fit.proxy import parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.optics.io import read_lens
    from calibration.optics.psf.map import PSFMapSettings, psf_map

    basis_path = tmp_path / "e9_basis.npz"
    code = main(["calib", "basis", str(e9_zmx), "-o", str(basis_path), "--draws", "3", "--grid", "2", "2",
                 "--components", "2", "--workers", "1"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "3 lenses drawn" in out.out and basis_path.is_file()

    lens = read_lens(e9_zmx)
    space = parameter_space(lens, ["s17.thickness"])
    truth = space.apply(0.7 * space.tolerance)
    pm = psf_map(truth, PSFMapSettings(grid=(2, 3), channels=("G",), n=32, pupil_samples=32, n_wavelengths=2))
    obs_path = tmp_path / "obs.json"
    synthetic_observations(pm, noise=0.003, rng=1).save(obs_path)
    dev = tmp_path / "dev"
    code = main(["calib", "fit", "--lens", str(e9_zmx), "--measured", str(obs_path), "-o", str(dev),
                 "--n-params", "1", "--max-iter", "3", "--workers", "1", "--restarts", "0",
                 "--basis", str(basis_path), "--components", "2"])
    out = capsys.readouterr()
    assert code == 0, out.err
    cal = DeviceCalibration.load(dev / "device.json")
    check_calibration(cal, DescriptorBasis.load(basis_path))
    assert cal.grid == (2, 2) and cal.descriptor.shape[2] == 2 and cal.lens == e9_zmx.stem
    assert cal.source["measured"] == "obs.json" and len(cal.source["sha256"]) == 64
    assert "device.json" in out.out

    # a basis of another design is refused before the fit, in one line, with no folder left
    e1_basis = tmp_path / "e1_basis.npz"
    b = DescriptorBasis.load(basis_path)
    DescriptorBasis(b.lens, "0" * 64, b.grid, b.channels, b.mean, b.components, b.scales, b.explained,
                    b.draws, b.sensor).save(e1_basis)
    code = main(["calib", "fit", "--lens", str(e9_zmx), "--measured", str(obs_path), "-o", str(tmp_path / "x"),
                 "--basis", str(e1_basis)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "another design" in err and "e1_basis.npz" in err and "\n" not in err
    assert not (tmp_path / "x").exists()
    # the loop writes one too, from a lens file only
    code = main(["calib", "loop", "--lens", "parametric", "--measured", str(obs_path), "-o", str(tmp_path / "y"),
                 "--basis", str(basis_path)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "parametric" in err and "\n" not in err and not (tmp_path / "y").exists()


def test_a_simulated_capture_carries_the_calibration_it_is_given(capsys, tmp_path, e9_zmx):
    from isp.io.read import read_raw

    cal = DeviceCalibration(e9_zmx.stem, "d" * 64, "b" * 64, np.zeros((5, 7, 16)))
    dev = cal.save(tmp_path / "device.json")
    out = tmp_path / "c.dng"
    assert main(["calib", "simulate", str(e9_zmx), "-o", str(out), "--size", "400,300", "--device", str(dev)]) == 0
    capsys.readouterr()
    assert read_raw(out).meta.device_calibration == cal.to_text()
    bad = tmp_path / "bad.json"
    bad.write_text("[]")
    code = main(["calib", "simulate", str(e9_zmx), "-o", str(tmp_path / "d.dng"), "--device", str(bad)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "bad.json" in err and "\n" not in err and not (tmp_path / "d.dng").exists()


def test_the_basis_a_fit_writes_on_is_the_profile_s_for_its_design(e9_lens):
    """``--basis auto``: the basis a registered profile ships for the lens's
    design (the packaged e9's), none for another design; ``none``: none."""
    from calibration.fit.device import find_basis, resolve_basis
    from calibration.optics.io import read_lens
    from isp.profiles import get_profile
    from tests.helpers import data_file

    assert find_basis(e9_lens) == get_profile("e9").basis
    assert resolve_basis("auto", e9_lens).design == design_key(e9_lens)
    assert resolve_basis("none", e9_lens) is None
    e2 = read_lens(data_file("lenses", "phone", "US-12210142-B2-e2.zmx"))
    assert find_basis(e2) is None and resolve_basis(None, e2) is None
    with pytest.raises(InputError, match="another design"):
        resolve_basis(get_profile("e9").basis, e2)
