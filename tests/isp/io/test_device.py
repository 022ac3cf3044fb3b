"""The device/v1 file as the correction stage reads it (kind: property):
the descriptor's interpolation over the frame against torch's
``grid_sample`` (the network side's oracle), and its edges."""

from __future__ import annotations

import numpy as np
import pytest

from isp.io.device import DeviceCalibration, descriptor_map
from modules.correction import field_coordinates_at

pytestmark = pytest.mark.property


@pytest.mark.parametrize("grid, size", [((5, 7), (30, 44)), ((2, 3), (17, 9)), ((1, 4), (6, 20))])
def test_descriptor_map_is_grid_sample_at_the_field_position(grid, size):
    torch = pytest.importorskip("torch")
    import torch.nn.functional as F

    rng = np.random.default_rng(1)
    d = rng.normal(size=(*grid, 3))
    rows, cols = np.arange(size[0]), np.arange(size[1])
    ours = descriptor_map(d, rows, cols, size)
    f = field_coordinates_at(rows, cols, size)                       # (2, h, w): x, y in (-1, 1)
    g = torch.from_numpy(np.stack([f[0], f[1]], axis=-1)[None]).double()
    ref = F.grid_sample(torch.from_numpy(d.transpose(2, 0, 1)[None]).double(), g, mode="bilinear",
                        padding_mode="border", align_corners=False)[0].numpy()
    assert ours.shape == (3, *size)
    assert np.allclose(ours, ref, atol=1e-6)


def test_descriptor_map_holds_region_centres_and_is_flat_past_the_outer_ones():
    d = np.arange(6.0).reshape(2, 3, 1)
    h, w = 20, 30                        # regions of 10 × 10 px: centres at 4.5 and 14.5, ...
    m = descriptor_map(d, np.array([4.5, 14.5, 0, 19]), np.array([4.5, 14.5, 24.5, 0, 29]), (h, w))[0]
    assert m[0, :3].tolist() == [0, 1, 2] and m[1, :3].tolist() == [3, 4, 5]
    assert m[2, 3] == 0 and m[3, 4] == 5                             # corners: the corner region's value


def test_a_calibration_interpolates_its_own_descriptor(tmp_path):
    d = np.random.default_rng(2).normal(size=(5, 7, 4))
    cal = DeviceCalibration("lens", "design", "basis", d)
    back = DeviceCalibration.load(cal.save(tmp_path / "dev.json"))
    rows, cols = np.arange(0, 40, 3), np.arange(0, 56, 5)
    assert back.components == 4 and back.grid == (5, 7)
    assert np.allclose(back.field_map(rows, cols, (40, 56)), descriptor_map(d, rows, cols, (40, 56)), atol=1e-3)


def test_a_dng_carries_its_module_calibration_in_dng_private_data(tmp_path):
    from isp import CFA, CameraMeta
    from isp.io.device import PRIVATE_DATA_NAME
    from isp.io.dng_write import write_dng
    from isp.io.read import read_raw

    cal = DeviceCalibration("lens", "d" * 64, "b" * 64, np.random.default_rng(3).normal(size=(5, 7, 16)),
                            source={"measured": "chart.dng"})
    meta = CameraMeta(cfa=CFA.RGGB, white_level=(1023.0,), color_matrix_1=np.eye(3), calibration_illuminant_1=21,
                      as_shot_neutral=(0.5, 1.0, 0.6), device_calibration=cal.to_text())
    path = write_dng(tmp_path / "c.dng", np.full((96, 128), 300, np.uint16), meta)
    import tifffile

    with tifffile.TiffFile(path) as t:
        raw = bytes(t.pages[0].tags[50740].value)
    assert raw.startswith(PRIVATE_DATA_NAME)          # DNG 1.7: a NUL-terminated name, the maker's first
    back = read_raw(path).meta.device_calibration
    assert back == cal.to_text()
    assert np.allclose(DeviceCalibration.from_text(back).descriptor, cal.descriptor, atol=1e-3)
    # `isp info` says what it carries, not the numbers
    import json

    from isp.cli.main import main

    assert main(["info", str(path), "--json", str(tmp_path / "info.json")]) == 0
    shown = json.loads((tmp_path / "info.json").read_text())["device_calibration"]
    assert shown["lens"] == "lens" and shown["grid"] == [5, 7] and shown["components"] == 16
    assert "descriptor" not in shown


def test_another_makers_private_data_is_not_a_calibration(raw_file):
    from isp.io.read import read_raw

    # the GoPro FUSION carries GoPro's own DNGPrivateData
    assert read_raw(raw_file("gopro_FUSION_GPFR7066.dng")).meta.device_calibration == ""


def test_a_capture_names_its_module_by_its_serial_number(raw_file, tmp_path):
    """CameraSerialNumber (DNG 50735) is read from a real camera's DNG, and
    written and read back; a calibration's measurement records it."""
    from isp import CFA, CameraMeta
    from isp.io.dng_write import write_dng
    from isp.io.read import camera_serial, read_raw
    from calibration.fit.device import measurement_source

    gopro = raw_file("gopro_HERO6_GOPR0024.dng")
    assert read_raw(gopro).meta.serial == "C32213DVT14025" == camera_serial(gopro)
    meta = CameraMeta(cfa=CFA.RGGB, white_level=(1023.0,), color_matrix_1=np.eye(3), calibration_illuminant_1=21,
                      as_shot_neutral=(0.5, 1.0, 0.6), serial="MOD-0042")
    path = write_dng(tmp_path / "chart.dng", np.full((96, 128), 300, np.uint16), meta)
    assert read_raw(path).meta.serial == "MOD-0042"
    src = measurement_source(path)
    assert src["serial"] == "MOD-0042" and src["measured"] == "chart.dng"
    assert DeviceCalibration("lens", "d", "b", np.zeros((1, 1, 1)), source=src).serial == "MOD-0042"
    assert "serial" not in measurement_source(tmp_path / "measurements.json")
    assert read_raw(write_dng(tmp_path / "none.dng", np.full((96, 128), 300, np.uint16),
                              meta.replace(serial=""))).meta.serial == ""
