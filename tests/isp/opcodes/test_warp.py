"""The warp opcodes (isp/opcodes/warp.py; DNG 1.7.1.0, chapter 7): the
DngOpcodesEditor WarpRectilinear sample blob, and the warps applied.

Kinds (each test marked): published (facts from the data README);
property (the mapping against the specification's equations written out
here, the resampling against the bicubic kernel written out here).
"""

from __future__ import annotations


import pytest

from isp.opcodes import (
    WarpRectilinear,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import opcode_blob as _blob


@pytest.mark.published
def test_published_warp_blob():
    """published: DngOpcodesEditor WarpRectilinear, one plane."""
    blob = _blob("DngOpcodesEditor_WarpRectilinear.bin")
    (op,) = parse_opcode_list(blob)
    assert isinstance(op, WarpRectilinear) and op.planes == 1
    assert op.radial == ((0.75, 0.25, 0.0, 0.0),) and op.tangential == ((0.0, 0.0),)
    assert (op.center_x, op.center_y) == (0.5, 0.5)
    assert serialize_opcode_list([op]) == blob


# -- applying -------------------------------------------------------------------

import numpy as np  # noqa: E402

from isp.opcodes import OpcodeContext, OpcodeError, WarpFisheye, WarpRectilinear2  # noqa: E402

H, W = 150, 200


def _keys(t, a=-0.75):
    """The bicubic kernel of the SDK (dng_resample_bicubic) and OpenCV."""
    t = np.abs(t)
    return np.where(t < 1, ((a + 2) * t - (a + 3)) * t * t + 1,
                    np.where(t < 2, ((a * t - 5 * a) * t + 8 * a) * t - 4 * a, 0.0))


def _resampled_ramp(pos):
    """What resampling the ramp v(x) = x at ``pos`` gives: the position cut
    to the 1/32-pixel lattice by truncation, then the four-tap kernel."""
    q = np.floor(32 * pos) / 32
    i, t = np.floor(q), q - np.floor(q)
    w = np.stack([_keys(t + 1), _keys(t), _keys(t - 1), _keys(t - 2)])
    return (w * (i + np.arange(-1, 3)[:, None, None])).sum(0) / w.sum(0)


def _spec_source(kr, kt, cx_rel, cy_rel):
    """DNG 1.7.1.0 ch. 7 WarpRectilinear, written out: normalised by the
    distance m from the centre to the farthest corner, r^2 = dx^2 + dy^2
    (at most 1), f = kr0 + kr1 r^2 + kr2 r^4 + kr3 r^6,
    x_s = cx + m (f dx + 2 kt0 dx dy + kt1 (r^2 + 2 dx^2)),
    y_s = cy + m (f dy + 2 kt1 dx dy + kt0 (r^2 + 2 dy^2))."""
    yy, xx = np.mgrid[:H, :W].astype(np.float64)
    cx, cy = cx_rel * W, cy_rel * H
    m = max(np.hypot(cx - a, cy - b) for a in (0, W) for b in (0, H))
    dx, dy = (xx - cx) / m, (yy - cy) / m
    r2 = np.minimum(dx * dx + dy * dy, 1.0)
    f = kr[0] + kr[1] * r2 + kr[2] * r2 ** 2 + kr[3] * r2 ** 3
    xs = cx + m * (f * dx + 2 * kt[0] * dx * dy + kt[1] * (r2 + 2 * dx * dx))
    ys = cy + m * (f * dy + 2 * kt[1] * dx * dy + kt[0] * (r2 + 2 * dy * dy))
    return xs, ys


def _ramps():
    yy, xx = np.mgrid[:H, :W].astype(np.float32)
    return xx, yy


@pytest.mark.property
def test_warp_rectilinear_maps_pixels_as_the_specification_says():
    """A coordinate grid (plane 0 = column, plane 1 = row) through a radial
    + tangential warp off centre returns, at every pixel whose source lies
    inside, the specification's source position as the kernel resamples
    it: the mapping and the resampling both checked analytically."""
    op = WarpRectilinear(((1.0, 0.05, -0.02, 0.01),), ((0.002, -0.003),), 0.45, 0.55)
    xx, yy = _ramps()
    out = op.apply(np.stack([xx, yy], -1), OpcodeContext(3))
    xs, ys = _spec_source(op.radial[0], op.tangential[0], 0.45, 0.55)
    inside = (xs > 1) & (xs < W - 3) & (ys > 1) & (ys < H - 3)
    assert inside.mean() > 0.9
    assert np.abs(out[..., 0] - _resampled_ramp(xs))[inside].max() < 1e-4
    assert np.abs(out[..., 1] - _resampled_ramp(ys))[inside].max() < 1e-4
    # and the displacement is real: up to several pixels at the corners
    assert np.abs(xs - xx).max() > 3


@pytest.mark.property
def test_lateral_colour_each_plane_its_own_coefficients():
    """Three planes with their own scale (the FUSION's kind of lateral
    colour correction): plane p of an x-ramp image returns x_s of plane p's
    coefficients; an identity plane is copied, its outer rows and columns
    taken as the SDK's resampler takes them."""
    op = WarpRectilinear(((1.002, 0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.997, 0.01, 0.0, 0.0)),
                         ((0.0, 0.0),) * 3)
    xx, _ = _ramps()
    out = op.apply(np.stack([xx, xx, xx], -1), OpcodeContext(3))
    for p in (0, 2):
        xs, ys = _spec_source(op.radial[p], op.tangential[p], 0.5, 0.5)
        inside = (xs > 1) & (xs < W - 3) & (ys > 1) & (ys < H - 3)
        assert np.abs(out[..., p] - _resampled_ramp(xs))[inside].max() < 1e-4
    assert np.array_equal(out[2:-3, 1:-3, 1], xx[2:-3, 1:-3])
    assert np.array_equal(out[:, 0, 1], xx[:, 1]) and np.array_equal(out[:, -1, 1], xx[:, -4])
    assert np.ptp(out[..., 0] - out[..., 2]) > 0.5        # the planes moved apart


@pytest.mark.property
def test_window_of_the_image_uses_the_image_geometry():
    """The same warp on a window of the image (origin (10, 20)) gives the
    whole image's result cut to the window, away from the window's edges."""
    op = WarpRectilinear(((1.0, 0.03, 0.0, 0.0),), ((0.001, 0.0),), 0.5, 0.5)
    rng = np.random.default_rng(0)
    img = rng.random((H, W)).astype(np.float32)
    whole = op.apply(img, OpcodeContext(3))
    win = img[10:130, 20:190]
    part = op.apply(win, OpcodeContext(3, origin=(10, 20), image_size=(H, W)))
    assert np.allclose(part[8:-8, 8:-8], whole[18:122, 28:182], atol=1e-6)


@pytest.mark.property
def test_fisheye_and_rectilinear2_ratios():
    """WarpFisheye: f = atan(r) (k0 + k1 t^2 + ...) / r (1 at r = 0);
    WarpRectilinear2: the polynomial in r over its valid range, or its
    reciprocal."""
    r = np.array([0.0, 0.2, 0.5, 0.9])
    fish = WarpFisheye(((0.9, -0.1, 0.02, 0.0),))
    t = np.arctan(r)
    with np.errstate(invalid="ignore", divide="ignore"):
        expect = np.where(r > 0, t * (0.9 - 0.1 * t ** 2 + 0.02 * t ** 4) / r, 1.0)
    assert np.allclose(fish.ratio(0, r ** 2), expect, rtol=1e-12)
    k = (1.0, 0.01, 0.02) + (0.0,) * 12
    w2 = WarpRectilinear2((k,), ((0.0, 0.0),), ((0.1, 0.8),))
    rr = np.clip(r, 0.1, 0.8)
    assert np.allclose(w2.ratio(0, r ** 2), 1 + 0.01 * rr + 0.02 * rr ** 2, rtol=1e-12)
    w2r = WarpRectilinear2((k,), ((0.0, 0.0),), ((0.0, 1.0),), reciprocal=1)
    assert np.allclose(w2r.ratio(0, r ** 2), 1 / (1 + 0.01 * r + 0.02 * r ** 2), rtol=1e-12)
    assert np.allclose(w2r.ratio_minus_one(0, r ** 2), w2r.ratio(0, r ** 2) - 1, atol=1e-15)


@pytest.mark.property
def test_warp_plane_count_must_fit():
    op = WarpRectilinear(((1.0, 0.01, 0.0, 0.0),) * 2, ((0.0, 0.0),) * 2)
    assert "2 planes of coefficients" in op.unsupported(3, 3)
    with pytest.raises(OpcodeError, match="WarpRectilinear: 2 planes of coefficients"):
        op.apply(np.zeros((8, 8, 3), np.float32), OpcodeContext(3))
    assert WarpRectilinear(((1.0, 0.01, 0.0, 0.0),) * 3, ((0.0, 0.0),) * 3).unsupported(2, 1) is None
