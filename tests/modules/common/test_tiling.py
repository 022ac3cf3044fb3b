"""Tiled execution (modules.common.tiling): the tiles cover the frame once, the
windows are aligned and padded by reflection, and a local operator run
tile by tile equals the whole-frame run when the margin covers its radius,
and not when it does not (kind: property)."""

from __future__ import annotations

import numpy as np
import pytest

from modules.common.tiling import plan_tiles, read_window, reflect_indices, run_tiled, split_axis, write_planes

pytestmark = pytest.mark.property


@pytest.mark.parametrize("n", [1, 2, 5, 16])
@pytest.mark.parametrize("pad", [0, 1, 3, 20])
def test_reflect_indices_is_numpy_reflect(n, pad):
    a = np.arange(n)
    expect = np.pad(a, pad, mode="reflect") if n > 1 else np.zeros(n + 2 * pad, int)
    assert np.array_equal(a[reflect_indices(-pad, n + pad, n)], expect)


@pytest.mark.parametrize("n", [1, 7, 64, 700, 901])
@pytest.mark.parametrize("tile,margin,mult", [(0, 8, 4), (64, 8, 4), (256, 30, 4), (256, 7, 1), (40, 3, 2)])
@pytest.mark.parametrize("border", [None, 0, 5])
def test_cores_cover_axis_once_aligned(n, tile, margin, mult, border):
    spans = split_axis(n, tile, margin, mult, border)
    m = -(-margin // mult) * mult
    b = m if border is None else min(-(-border // mult) * mult, m)
    n_pad = -(-n // mult) * mult
    cover = np.zeros(n, int)
    for s in spans:
        cover[s.core_start:s.core_stop] += 1
        size = s.win_stop - s.win_start
        assert s.core_start % mult == 0 and size % mult == 0
        # between tiles the margin; beyond the frame exactly the border, as in the whole-frame run
        assert s.win_start == -b if s.core_start == 0 else s.core_start - s.win_start >= margin
        assert s.win_stop == n_pad + b if s.core_stop == n else s.win_stop - s.core_stop >= margin
        if len(spans) > 1:
            assert size <= tile
    assert np.all(cover == 1)
    assert len({s.win_stop - s.win_start for s in spans[1:-1]}) <= 1  # one size between the edges


def test_tile_too_small_for_margin_is_refused():
    with pytest.raises(ValueError, match="at least 68 px"):
        split_axis(100, 64, 32, 4)


def _box(x: np.ndarray, r: int) -> np.ndarray:
    """(C, h, w) → mean over a (2r+1)² box with zero padding (as a network's
    convolutions pad): a local operator of radius r, wrong near the window edge."""
    p = np.pad(x.astype(np.float64), ((0, 0), (r, r), (r, r)))  # float64: cumsum rounding
    c = np.pad(p.cumsum(1).cumsum(2), ((0, 0), (1, 0), (1, 0)))
    k = 2 * r + 1
    return (c[:, k:, k:] - c[:, :-k, k:] - c[:, k:, :-k] + c[:, :-k, :-k]) / k ** 2


def test_tiled_equals_whole_frame_when_margin_covers_radius(rng):
    img = rng.random((150, 170, 3), dtype=np.float32)
    op = lambda x, rows, cols: _box(x, 5)
    whole = run_tiled(op, img, tile=0, margin=5)
    tiled = run_tiled(op, img, tile=48, margin=5)
    assert len(plan_tiles(img.shape[:2], 48, 5)) > 9
    assert np.abs(tiled - whole).max() < 1e-5
    # the whole-frame run is the operator on the reflect-padded frame
    ref = _box(np.pad(img, ((5, 5), (5, 5), (0, 0)), mode="reflect").transpose(2, 0, 1), 5)
    assert np.abs(whole - ref[:, 5:-5, 5:-5].transpose(1, 2, 0)).max() < 1e-5


@pytest.mark.parametrize("border", [0, 2, 4])
def test_a_narrower_border_context_leaves_no_seam(rng, border):
    # the reflected surround beyond the frame may be narrower than the seam margin: the
    # tiles still reproduce the whole-frame run made with that surround, exactly, because
    # the edge windows end where the whole frame's does (module docstring)
    img = rng.random((150, 170, 3), dtype=np.float32)
    op = lambda x, rows, cols: _box(x, 5)
    whole = run_tiled(op, img, tile=0, margin=6, multiple=2, border=border)
    tiled = run_tiled(op, img, tile=48, margin=6, multiple=2, border=border)
    assert np.abs(tiled - whole).max() < 1e-5
    # ... and the surround is what the frame's edge pixels see: zero padding past it
    ref = _box(np.pad(np.pad(img, ((border,) * 2, (border,) * 2, (0, 0)), mode="reflect"),
                      ((6 - border,) * 2, (6 - border,) * 2, (0, 0))).transpose(2, 0, 1), 5)
    assert np.abs(whole - ref[:, 6:-6, 6:-6].transpose(1, 2, 0)).max() < 1e-5
    if border < 5:   # a narrower surround changes the edge pixels
        assert np.abs(whole - run_tiled(op, img, tile=0, margin=6, multiple=2)).max() > 1e-3


def test_seam_error_grows_as_margin_drops_below_radius(rng):
    """Proves the equality test above can fail."""
    img = rng.random((150, 170, 3), dtype=np.float32)
    op = lambda x, rows, cols: _box(x, 6)
    whole = run_tiled(op, img, tile=0, margin=6)
    err = [np.abs(run_tiled(op, img, tile=48, margin=m) - whole).max() for m in (6, 4, 2, 0)]
    assert err[0] < 1e-5 and err[1] > 1 / 255 and err[1] < err[2] < err[3]


def test_operator_sees_frame_positions(rng):
    img = np.zeros((37, 53, 1), np.float32)

    def where(x, rows, cols):
        return np.stack([np.broadcast_to(rows[:, None], x.shape[1:]),
                         np.broadcast_to(cols[None, :], x.shape[1:])]).astype(np.float32)

    out = run_tiled(where, img, tile=16, margin=3, multiple=2, out_channels=2)
    yy, xx = np.mgrid[:37, :53]
    assert np.array_equal(out[..., 0], yy) and np.array_equal(out[..., 1], xx)


def test_wrong_operator_output_is_named():
    with pytest.raises(ValueError, match="tile operator returned shape"):
        run_tiled(lambda x, r, c: x[:, 1:], np.zeros((8, 8, 3), np.float32), tile=0, margin=0)


def test_progress_bar_on_request(capsys):
    run_tiled(lambda x, r, c: x, np.zeros((40, 40, 3), np.float32), tile=16, margin=2, progress=True,
              desc="corr")
    err = capsys.readouterr().err
    assert "corr" in err and "tile" in err


@pytest.mark.parametrize("dtype", [np.float32, np.float16, np.float64])
@pytest.mark.parametrize("channels", [1, 3, 5])
def test_plane_copies_equal_numpy_on_strided_views(rng, dtype, channels):
    # the OpenCV (de-)interleave paths and the numpy fallback give the same bytes
    image = rng.random((40, 50, channels)).astype(dtype)
    rows, cols = np.arange(5, 30), np.r_[2, 1, 0, 0:20]   # a reflected border: a gathered copy
    for r, c in ((rows, cols), (rows, np.arange(3, 40))):  # and a plain view with strided rows
        buf = np.full((channels + 2, r.size, c.size), -1, dtype)
        read_window(image, r, c, buf)
        assert np.array_equal(buf[:channels], image[r][:, c].transpose(2, 0, 1))
        assert np.all(buf[channels:] == -1)   # the extra channels are left alone
    out = np.zeros((30, 60, channels), dtype)
    planes = rng.random((channels, 20, 30)).astype(dtype)
    write_planes(out[4:24, 7:37], planes)
    assert np.array_equal(out[4:24, 7:37], planes.transpose(1, 2, 0))
    out[4:24, 7:37] = 0
    assert not out.any()   # nothing written outside the view


@pytest.mark.parametrize("dtype", [np.float32, np.float16, np.uint8])
def test_windows_reaching_past_the_border_read_as_fancy_indexing(rng, dtype):
    # property: whatever the window (folded once by OpenCV's reflecting border, folded
    # several times, or inside), the gathered window is image[rows][:, cols]
    from modules.common.tiling import _gather

    image = (rng.random((30, 40, 3)) * 200).astype(dtype)
    for _ in range(500):
        r0, c0 = int(rng.integers(-40, 30)), int(rng.integers(-50, 40))
        rows = reflect_indices(r0, r0 + int(rng.integers(1, 70)), 30)
        cols = reflect_indices(c0, c0 + int(rng.integers(1, 90)), 40)
        assert np.array_equal(_gather(image, rows, cols), image[rows][:, cols]), (r0, c0)


@pytest.mark.parametrize("packing", [1, 2])
def test_tiles_in_flight_at_once_give_the_same_frame(rng, packing):
    # workers > 1 runs tiles side by side on threads, each with its own window buffer:
    # the same windows, the same cores, so bit for bit the sequential frame
    img = rng.random((150, 170, 3), dtype=np.float32)
    seen = []

    def op(x, rows, cols):
        seen.append(x.ctypes.data)
        return _box(x, 4) * 2
    one = run_tiled(op, img, tile=48, margin=6, multiple=2, packing=packing)
    buffers_one = set(seen)
    seen.clear()
    three = run_tiled(op, img, tile=48, margin=6, multiple=2, packing=packing, workers=3)
    assert np.array_equal(one, three)
    assert len(buffers_one) == 1 and 1 < len(set(seen)) <= 3   # a buffer per worker, reused


def test_an_operator_returning_its_window_is_stitched_before_the_buffer_is_reused(rng):
    # the identity returns a view of the worker's buffer: stitched before another tile reuses it
    img = rng.random((150, 170, 3), dtype=np.float32)
    out = run_tiled(lambda x, rows, cols: x, img, tile=40, margin=4, workers=2)
    assert np.array_equal(out, img)


def test_an_error_in_a_tile_on_a_worker_reaches_the_caller(rng):
    img = rng.random((100, 100, 3), dtype=np.float32)

    def op(x, rows, cols):
        if rows[0] > 40:
            raise RuntimeError("tile failed")
        return x
    with pytest.raises(RuntimeError, match="tile failed"):
        run_tiled(op, img, tile=48, margin=4, workers=2)
