"""The pixel-MSE competitor of the proxy fit (calibration.fit.pixel) and
the edge images of synthetic devices (proxy_synth, return_edges); kind:
property."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from calibration.fit.pixel import _steps

pytestmark = pytest.mark.property


@pytest.fixture(scope="module")
def device(e9_lens):
    """e9 with focus and a decenter perturbed, measured on a 3 × 4 grid."""
    from calibration.fit.proxy import focus_name, parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.optics.psf.map import PSFMapSettings, psf_map
    from isp.runtime.executor import create_executor

    lens = e9_lens
    names = [focus_name(lens), "e1.decenter_x"]
    space = parameter_space(lens, names)
    truth = np.array([1.0, 0.8])
    with warnings.catch_warnings():     # the corner PSF is truncated by the small window: immaterial here
        warnings.simplefilter("ignore", UserWarning)
        pm = psf_map(space.apply(truth * space.tolerance),
                     PSFMapSettings(grid=(3, 4), channels=("G",), n=32, pupil_samples=32, n_wavelengths=2),
                     cache=False, executor=create_executor("serial"))
    obs, edges = synthetic_observations(pm, noise=0.004, return_edges=True, rng=1)
    return lens, names, truth, pm, obs, edges


def test_return_edges_matches_observations(device):
    from calibration.fit.observations import Observations
    from calibration.fit.synthetic_devices import synthetic_observations

    _, _, _, pm, obs, edges = device
    assert len(edges) == len(obs) == 24
    plain = synthetic_observations(pm, noise=0.004, rng=1)
    assert isinstance(plain, Observations)                    # default unchanged
    np.testing.assert_array_equal(plain.sfra, obs.sfra)       # same noise draws
    for i, e in enumerate(edges):
        assert e.image.shape == e.size == (int(obs.roi[i][3]), int(obs.roi[i][2]))
        assert tuple(e.box) == tuple(int(v) for v in obs.roi[i])
        assert e.center_px == (obs.x_px[i], obs.y_px[i])
        assert 0.5 * e.noise < np.std(e.image - e.clean) < 2.0 * e.noise
    # rendering through the truth PSF gives back the clean ROI
    e = edges[0]
    r, c = obs.region[0]
    np.testing.assert_allclose(e.render(pm.psf(r, c, "G").data, pm.pitch_um), e.clean, atol=1e-9)


def test_pixel_fit_moves_toward_truth(device):
    from calibration.fit.pixel import fit_pixel_mse
    from calibration.fit.forward_model import ModelSettings

    lens, names, truth, _, obs, edges = device
    fit = fit_pixel_mse(lens, obs, edges, names=names, settings=ModelSettings(pupil_samples=32, psf_n=32), max_iter=5)
    assert fit.u.shape == (2,) and np.all(np.abs(fit.u) <= 2.0)
    assert tuple(fit.space.names) == tuple(names)
    assert abs(fit.u[0] - truth[0]) < 0.3 * abs(truth[0])    # focus: from 1 tolerance off to < 0.3
    assert np.linalg.norm(fit.u - truth) < np.linalg.norm(truth)
    assert fit.mse_after < 0.5 * fit.mse_before
    assert fit.evaluations >= 3 and fit.seconds > 0
    assert fit.lens.perturbation.as_dict()[names[0]] == pytest.approx(fit.u[0] * fit.space.tolerance[0])
    assert fit.to_dict()["method"] == "pixel-mse"


def test_pixel_fit_rejects_mismatched_edges(device):
    from calibration.fit.pixel import fit_pixel_mse

    lens, names, _, _, obs, edges = device
    with pytest.raises(ValueError, match="edge images"):
        fit_pixel_mse(lens, obs, edges[:-1], names=names)


def test_steps_stay_in_bounds():
    lo, hi = np.full(3, -2.0), np.full(3, 2.0)
    h = _steps(np.array([0.0, -1.5, 1.95]), lo, hi, 0.1)
    np.testing.assert_allclose(h, [0.1, -0.15, -0.195])


@pytest.mark.parametrize("horizontal", [False, True])
@pytest.mark.parametrize("low, high", [(0.2, 0.8), (0.8, 0.2)])
def test_edge_offset_finds_a_known_shift(horizontal, low, high):
    """A Gaussian edge moved by 0.37 px along its normal is found 0.37 px
    away (ISO 12233 locates both), and moving it back restores the first
    one; the sign says which way, whatever the polarity."""
    from calibration.fit.pixel import edge_offset, register_edge
    from calibration.sfr.synthetic import render_slanted_edge

    shape = (64, 96) if not horizontal else (96, 64)
    c = ((shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0)
    moved = (c[0], c[1] + 0.37) if horizontal else (c[0] + 0.37, c[1])
    a = render_slanted_edge(shape, 5.0, 1.3, low=low, high=high, horizontal=horizontal)
    b = render_slanted_edge(shape, 5.0, 1.3, low=low, high=high, horizontal=horizontal, center=moved)
    off, axis = edge_offset(a, b)
    assert axis == (0 if horizontal else 1)
    assert off == pytest.approx(0.37, abs=0.01)
    back, applied = register_edge(a, b)
    assert applied == off
    assert np.max(np.abs(back - b)) < 2e-3 * abs(high - low)     # cubic spline on a 1.3 px blur
    assert np.max(np.abs(a - b)) > 0.05                         # the shift was visible before


def test_registered_ssim_keeps_blur_differences():
    """Registration takes a pure shift out of the SSIM, not a blur: a wider
    edge scores the same against the measurement registered or not, while
    the same edge merely shifted goes back to SSIM ≈ 1."""
    from skimage.metrics import structural_similarity as ssim

    from calibration.fit.pixel import register_edge
    from calibration.sfr.synthetic import render_slanted_edge

    meas = render_slanted_edge((64, 96), 5.0, 1.0, center=(47.5 + 0.3, 31.5))
    shifted = render_slanted_edge((64, 96), 5.0, 1.0)
    wider = render_slanted_edge((64, 96), 5.0, 1.6, center=(47.5 + 0.3, 31.5))
    assert ssim(shifted, meas, data_range=1.0) < 0.998             # 0.3 px costs 3e-3 on this ROI
    assert ssim(register_edge(shifted, meas)[0], meas, data_range=1.0) > 0.99999
    plain, reg = ssim(wider, meas, data_range=1.0), ssim(register_edge(wider, meas)[0], meas, data_range=1.0)
    assert plain < 0.992 and reg == pytest.approx(plain, abs=1e-5)


def test_edge_offset_refuses_mismatched_rois():
    from calibration.fit.pixel import edge_offset
    from calibration.sfr.synthetic import render_slanted_edge

    a = render_slanted_edge((64, 96), 5.0, 1.0)
    with pytest.raises(ValueError, match="one 2-D shape"):
        edge_offset(a, a[:, :90])
    with pytest.raises(ValueError, match="orientation"):
        edge_offset(a, render_slanted_edge((64, 96), 5.0, 1.0, horizontal=True))
