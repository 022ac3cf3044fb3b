"""The pupil layer (calibration/optics/psf/pupil.py): the SFR model's
batched path — many fields traced, and their pupils fitted, at once — equals
the per-field path (kind: property).

:mod:`calibration.fit.forward_model` traces and diffracts every field node
at once (one trace per wavelength, batched pupil fits and Debye sums); the
per-field functions are its oracle. Exact refactors agree to the tracer's
Newton tolerance (1e-12 mm), i.e. ~1e-10 of the PSF peak.
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.optics import trace as tr
from calibration.optics.psf import pupil

pytestmark = pytest.mark.property


def test_property_batched_rays_match_per_field_rays(batch):
    """property: field_pupil_rays (paraxial and real aiming) and the batched
    trace give every field the rays pupil_rays and _finish give it alone."""
    pl, fields, tn, singles = batch
    assert tn.valid.sum(axis=1).min() < 0.75 * tn.valid.shape[1]          # vignetting is exercised
    for k, one in enumerate(singles):
        node = tn.node(k)
        assert np.array_equal(node.ix, one.ix) and np.array_equal(node.iy, one.iy)
        for name in ("pos", "dirn", "opl", "chief_pos", "chief_dir"):
            np.testing.assert_allclose(getattr(node, name), getattr(one, name), rtol=0, atol=1e-11)
    grid = pupil.pupil_points(8)
    both = tr.field_pupil_rays(pl, fields, grid, 600.0)
    for k, f in enumerate(fields):
        one = tr.pupil_rays(pl, tuple(f), 8, 600.0, aiming="paraxial", pupil=grid)
        sl = slice(k * len(grid), (k + 1) * len(grid))
        np.testing.assert_allclose(both.origin[sl], one.origin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(both.direction[sl], one.direction, rtol=0, atol=1e-15)
        np.testing.assert_allclose(both.opl[sl], one.opl, rtol=0, atol=1e-12)
    with pytest.raises(tr.TraceError, match="aiming"):
        tr.field_pupil_rays(pl, fields, grid, 600.0, aiming="nope")


def test_property_batched_pupil_fit_matches_per_field_fit(batch):
    """property: the pupil fits of all fields at once (node_jacobians) equal
    the per-field fit; a field with too few rays for degree 4 takes the
    per-field path."""
    _, _, tn, singles = batch
    for k, one in enumerate(singles):
        np.testing.assert_allclose(tn.jac[k, tn.valid[k]], pupil.solid_angle_jacobian(one.p, one.dirn), rtol=1e-10)
        assert np.all(tn.jac[k, ~tn.valid[k]] == 0)
    few = tn.valid.copy()
    keep = np.flatnonzero(few[0])[:40]
    few[0] = False
    few[0, keep] = True
    j = pupil.node_jacobians(tn.p, tn.dirn, few)
    np.testing.assert_allclose(j[0, keep], pupil.solid_angle_jacobian(tn.p[keep], tn.dirn[0, keep]), rtol=1e-12)


def test_property_dropping_failed_rays_and_fitted_start_change_nothing(batch, monkeypatch):
    """property: dropping failed rays from a chunk (done without ``record``)
    and starting Newton from the fitted conic (trace._start_conic) leave
    the traced rays as the plain loop has them, to the Newton tolerance."""
    pl, fields, _, _ = batch
    rays = tr.field_pupil_rays(pl, fields, pupil.pupil_points(24), 520.0, aiming="real")
    fast = tr.trace_to_exit(pl, rays)
    kept = tr.trace_to_exit(pl, rays, record=True)            # carries failed rays as placeholders
    geo = tr._compile(pl, 520.0)
    assert any(s.start != (s.c, s.kc2) for s in geo if s.kind == tr._ASPHERE)
    monkeypatch.setattr(tr, "_start_conic", lambda c, kc2, *_: (c, kc2))
    base = tr.trace_to_exit(pl, rays)                         # Newton from the base conics
    assert not fast.valid.all()
    for other in (kept, base):
        assert np.array_equal(fast.status, other.status) and np.array_equal(fast.surface, other.surface)
        np.testing.assert_allclose(fast.position, other.position, rtol=0, atol=1e-11)
        np.testing.assert_allclose(fast.direction, other.direction, rtol=0, atol=1e-11)
        np.testing.assert_allclose(fast.opl, other.opl, rtol=0, atol=1e-11)
