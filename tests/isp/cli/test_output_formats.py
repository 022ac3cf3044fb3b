"""``isp process -o FILE``: the output's extension chooses the encoder
(JPEG, PNG 8/16 bit, TIFF 16 bit or float), each file with the sRGB ICC
profile and EXIF, read back by independent decoders; an unknown extension
or an undecodable raw is one line and exit code 2, with no output left
(kind: property)."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image, ImageCms

pytestmark = pytest.mark.property

SMALL = "SYNTHETIC_phone_S6meta_512x384.dng"


def _description(icc: bytes) -> str:
    return ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(icc))).strip()


@pytest.mark.parametrize("name,dtype", [("o.png", np.uint8), ("o.jpg", np.uint8), ("o.tif", np.uint16)])
def test_each_extension_gets_its_encoder(cli, tmp_path, raw_file, name, dtype):
    out = tmp_path / name
    code, stdout, stderr = cli("process", raw_file(SMALL), "-o", out, "-v")
    assert code == 0, stderr
    stage = {"png": "png", "jpg": "jpeg", "tif": "tiff"}[name.split(".")[1]]
    assert f"  {stage} " in stdout
    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == dtype and img.shape == (384, 512, 3)
    if name.endswith(".tif"):
        page = tifffile.TiffFile(out).pages[0]
        icc, exif = page.tags[34675].value, page.tags["ExifTag"].value
        assert exif["ColorSpace"] == 1 and page.tags[274].value == 1
    else:
        im = Image.open(out)
        icc, exif = im.info["icc_profile"], im.getexif()
        assert exif[0x0112] == 1 and exif.get_ifd(0x8769)[0xA001] == 1
    assert _description(icc) == "sRGB built-in"
    assert not list(tmp_path.glob(".*.tmp"))


def test_png_16_bit_and_the_same_pixels_as_8_bit(cli, tmp_path, raw_file):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert cli("process", raw_file(SMALL), "-o", a)[0] == 0
    code, _, stderr = cli("process", raw_file(SMALL), "-o", b, "--set", "png.bits=16")
    assert code == 0, stderr
    eight, sixteen = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
    assert sixteen.dtype == np.uint16 and len(np.unique(sixteen)) > 256
    assert np.abs(np.round(sixteen / 257.0) - eight).max() <= 1


def test_float_tiff_of_the_linear_look_holds_values_above_one(cli, tmp_path, raw_file):
    out = tmp_path / "scene.tif"
    code, stdout, stderr = cli("process", raw_file("tinydng_colorchart.dng"), "-o", out, "--look", "linear",
                               "--set", "tiff.bits=32", "--set", "luminance.exposure=2", "-v")
    assert code == 0, stderr
    assert "gamma" not in stdout and "linear sRGB profile" in stdout
    page = tifffile.TiffFile(out).pages[0]
    img = page.asarray()
    assert img.dtype == np.float32 and img.max() > 1.0
    assert _description(page.tags[34675].value) == "linear sRGB"


def test_unknown_extension_and_a_mismatched_override_are_refused(cli, tmp_path, raw_file):
    code, _, stderr = cli("process", raw_file(SMALL), "-o", tmp_path / "o.bmp")
    assert code == 2 and len(stderr.strip().splitlines()) == 1
    assert "o.bmp: unknown output format (extension '.bmp')" in stderr and ".tif/.tiff (TIFF)" in stderr
    code, _, stderr = cli("process", raw_file(SMALL), "-o", tmp_path / "o.png", "--set", "jpeg.quality=80")
    assert code == 2 and "written by the 'png' stage" in stderr
    assert list(tmp_path.iterdir()) == []


def test_undecodable_raw_is_one_line_and_exit_2(cli, tmp_path, raw_file):
    code, _, stderr = cli("process", raw_file("gopro_HERO6_GOPR0024_vc5.GPR"), "-o", tmp_path / "o.png")
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr
    assert "VC-5 (GoPro) compression (Compression = 9) is not supported by LibRaw" in stderr
    assert list(tmp_path.iterdir()) == []
