"""The DNG writer: files open in rawpy (LibRaw, an independent reader) and
round-trip through our reader (kinds: published — LibRaw reads the file
as we wrote it; property — round trips and refusals)."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from isp import CFA, CameraMeta, IspError
from isp.io.dng_write import write_dng
from isp.opcodes import AreaSpec, GainMap
from isp.io.read import read_raw


def _full_meta(h, w, cfa=CFA.GBRG):
    rng = np.random.default_rng(1)
    gm = tuple(
        GainMap.spanning_image(rng.uniform(1.0, 2.0, (9, 11, 1)).astype(np.float32),
                               area=AreaSpec(i, j, h, w, 0, 1, 2, 2))
        for i in range(2) for j in range(2))
    return CameraMeta(
        make="phone-isp", model="round trip", unique_camera_model="phone-isp round trip",
        cfa=cfa, orientation=6,
        black_level=np.array([[[64.0], [65.0]], [[63.0], [64.5]]]), white_level=(4095.0,),
        color_matrix_1=np.array([[0.7, -0.1, -0.05], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]]),
        color_matrix_2=np.array([[0.9, -0.3, -0.1], [-0.45, 1.25, 0.2], [-0.05, 0.15, 0.55]]),
        forward_matrix_1=np.array([[0.6, 0.3, 0.06], [0.25, 0.8, -0.05], [0.02, -0.2, 1.0]]),
        forward_matrix_2=np.array([[0.55, 0.35, 0.06], [0.2, 0.85, -0.05], [0.01, -0.3, 1.1]]),
        camera_calibration_1=np.diag([1.01, 1.0, 0.99]), camera_calibration_2=np.diag([1.02, 1.0, 0.98]),
        calibration_illuminant_1=21, calibration_illuminant_2=17,
        analog_balance=(1.0, 1.0, 1.0), as_shot_neutral=(0.512345, 1.0, 0.634567),
        baseline_exposure=-0.75, noise_profile=((3.1e-4, 2.2e-6),),
        opcodes={2: gm}, exposure_time_s=1 / 120, f_number=1.9, iso=250.0, focal_length_mm=5.6,
        datetime="2026:11:21 10:11:12", lens="test lens 5.6mm", pixel_pitch_um=1.12,
    )


@pytest.mark.published
def test_bayer_round_trip_through_rawpy_and_reader(tmp_path, rng):
    h, w = 96, 128
    data = rng.integers(60, 4096, (h, w)).astype(np.uint16)
    meta = _full_meta(h, w)
    path = write_dng(tmp_path / "rt.dng", data, meta)

    # an independent reader (LibRaw) opens it and sees the same pixels, pattern, levels
    with rawpy.imread(str(path)) as r:
        assert np.array_equal(r.raw_image, data)
        p = np.where(r.raw_pattern == 3, 1, r.raw_pattern)
        assert CFA.from_pattern(p) is CFA.GBRG
        assert r.white_level == 4095
        assert sorted(r.black_level_per_channel) == [63, 64, 64, 65]  # LibRaw rounds per channel
        # LibRaw honours the written Orientation 6 (90° CW): width and height swap
        assert r.postprocess(no_auto_bright=True).shape == (w, h, 3)

    f = read_raw(path)
    m = f.meta
    assert np.array_equal(f.data, data.astype(np.float32))
    assert m.cfa is CFA.GBRG and m.orientation == 6
    assert np.allclose(m.black_level, meta.black_level)
    assert m.white_level == (4095.0,)
    for name in ("color_matrix_1", "color_matrix_2", "forward_matrix_1", "forward_matrix_2",
                 "camera_calibration_1", "camera_calibration_2"):
        assert np.allclose(getattr(m, name), getattr(meta, name), atol=1e-6), name
    assert (m.calibration_illuminant_1, m.calibration_illuminant_2) == (21, 17)
    assert m.as_shot_neutral == pytest.approx(meta.as_shot_neutral, abs=1e-6)
    assert m.baseline_exposure == pytest.approx(-0.75)
    assert np.allclose(m.noise_profile, meta.noise_profile)
    assert len(m.opcodes[2]) == 4
    for a, b in zip(m.opcodes[2], meta.opcodes[2]):
        assert a.to_bytes() == b.to_bytes()
    assert m.make == "phone-isp" and m.model == "round trip"
    assert m.exposure_time_s == pytest.approx(1 / 120) and m.f_number == pytest.approx(1.9)
    assert m.iso == 250 and m.focal_length_mm == pytest.approx(5.6)
    assert m.datetime == "2026:11:21 10:11:12" and m.lens == "test lens 5.6mm"
    assert m.pixel_pitch_um == pytest.approx(1.12, rel=1e-6)
    assert m.notes == ()


@pytest.mark.property
def test_active_area_crop_and_linearisation_round_trip(tmp_path, rng):
    h, w = 70, 100
    data = rng.integers(0, 1024, (h, w)).astype(np.uint16)
    table = (np.arange(1024) * 4).astype(np.uint16)   # 10-bit → 12-bit
    meta = CameraMeta(cfa=CFA.RGGB, white_level=(4092.0,), linearization_table=table,
                      active_area=(2, 4, 66, 100), default_crop=(3, 1, 90, 60),
                      color_matrix_1=np.eye(3), calibration_illuminant_1=21)
    f = read_raw(write_dng(tmp_path / "crop.dng", data, meta))
    assert f.meta.active_area == (2, 4, 66, 100)
    assert f.shape == (60, 90) and f.meta.origin == (1, 3)
    # odd crop origin (row 1, col 3) shifts the phase: RGGB → seen from (1, 1) = BGGR
    assert f.meta.cfa is CFA.BGGR
    assert "LinearizationTable" in f.meta.applied_by_decoder
    expect = table[data[2 + 1:2 + 61, 4 + 3:4 + 93]].astype(np.float32)
    assert np.array_equal(f.data, expect)


@pytest.mark.property
def test_linear_dng_round_trip(tmp_path, rng):
    data = rng.integers(0, 65535, (40, 60, 3)).astype(np.uint16)
    meta = CameraMeta(cfa=None, white_level=(65535.0,), color_matrix_1=np.eye(3),
                      calibration_illuminant_1=21, as_shot_neutral=(0.5, 1.0, 0.7))
    f = read_raw(write_dng(tmp_path / "lin.dng", data, meta))
    assert f.meta.linear_raw and f.shape == (40, 60, 3)
    assert np.array_equal(f.data, data.astype(np.float32))


@pytest.mark.property
def test_writer_refuses_bad_input_and_leaves_no_file(tmp_path):
    meta = CameraMeta(cfa=CFA.RGGB)
    with pytest.raises(IspError, match="uint16"):
        write_dng(tmp_path / "a.dng", np.zeros((4, 4), np.float32), meta)
    bad = meta.replace(baseline_exposure=float("nan"))
    with pytest.raises(IspError, match="non-finite"):
        write_dng(tmp_path / "b.dng", np.zeros((4, 4), np.uint16), bad)
    assert list(tmp_path.iterdir()) == []
