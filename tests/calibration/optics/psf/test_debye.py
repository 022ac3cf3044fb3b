"""The Debye sums (calibration/optics/psf/debye.py): the batched sums of
many fields = the per-field PSFs, and the phasor tables by doubling = the
exponential (kind: property).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from calibration.optics.psf import debye, methods, pupil, sampling

pytestmark = pytest.mark.property


@pytest.mark.parametrize("dz_um", [0.0, 4.0])
def test_property_batched_debye_psfs_match_per_field_psfs(batch, dz_um):
    """property: debye_node_psfs in complex128 gives the per-field Debye PSFs
    (debye_samples of reference_sphere) to 1e-9 of the peak, in focus and
    with a per-field image-plane shift; its complex64 default stays within
    1e-6."""
    _, _, tn, singles = batch
    o = sampling.grid_offsets_mm(24, 0.5)
    z = tn.z_image + dz_um * 1e-3 * np.array([1.0, -1.0, 0.5, 0.0])
    centre = tn.chief_image_points(z)

    def per_field(node, k):
        return methods.monochromatic_samples(pupil.reference_sphere(node, centre[k]), "debye", o, o)

    ref = np.stack([per_field(tn.node(k, z[k]), k)[0] for k in range(len(tn))])
    single = np.stack([per_field(dataclasses.replace(one, z_image=z[k]), k)[0] for k, one in enumerate(singles)])
    np.testing.assert_allclose(single, ref, rtol=0, atol=1e-9 * ref.max())
    exact = debye.debye_node_psfs(tn, centre, z, o, o, dtype=np.complex128)
    np.testing.assert_allclose(exact, ref, rtol=0, atol=1e-9 * ref.max())
    np.testing.assert_allclose(debye.debye_node_psfs(tn, centre, z, o, o), ref, rtol=0, atol=1e-6 * ref.max())
    # and each field's window energy is the per-field PSF's (PSF.window_energy)
    e_ref = [per_field(tn.node(k, z[k]), k)[1] for k in range(len(tn))]
    np.testing.assert_allclose(debye.debye_node_psfs(tn, centre, z, o, o, dtype=np.complex128, energy=True)[1], e_ref,
                               rtol=1e-9)


@pytest.mark.parametrize("n", [1, 2, 7, 32])
def test_property_phasor_doubling_is_the_exponential(n):
    """property: the phasor tables by doubling equal exp(i k o)·scale."""
    rng = np.random.default_rng(2)
    k = rng.uniform(-2e4, 2e4, (2, 50))
    o = (np.arange(n) - n // 2) * 4e-4
    scale = rng.standard_normal((2, 50)) + 1j * rng.standard_normal((2, 50))
    ref = scale[..., None, :] * np.exp(1j * k[..., None, :] * o[:, None])
    np.testing.assert_allclose(debye.phasors(k, o, scale=scale), ref, rtol=1e-12)   # phases up to 130 rad
    np.testing.assert_allclose(debye.phasors(k, o, scale=scale, dtype=np.complex64), ref, rtol=2e-6)
