"""TIFF stage: files read back by independent readers (tifffile, libtiff
through OpenCV), the ICC profile read by Pillow's ImageCms, the EXIF IFD
read by tifffile, orientation against Pillow's exif_transpose (kind:
published); float files of linear values, deflate, and what is refused
(kind: property)."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image, ImageCms, ImageOps

from isp import ConfigError, Domain, Frame, Pipeline, create_stage
from tests.helpers import display_ramp, encoder_meta

META = encoder_meta()



def _page(data: bytes):
    return tifffile.TiffFile(io.BytesIO(data)).pages[0]


def _profile_description(page) -> str:
    return ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(page.tags[34675].value))).strip()


@pytest.mark.published
@pytest.mark.parametrize("compression", ["none", "deflate"])
def test_16_bit_round_trip_icc_and_exif(compression):
    rgb = display_ramp()
    out = create_stage("tiff", compression=compression)(Frame(rgb, Domain.DISPLAY_RGB, META))
    data = bytes(out.data)
    expect = np.round(rgb.astype(np.float64) * 65535).astype(np.uint16)
    page = _page(data)
    assert page.dtype == np.uint16 and page.photometric == tifffile.PHOTOMETRIC.RGB
    assert int(page.compression) == (1 if compression == "none" else 8)
    assert np.array_equal(page.asarray(), expect)
    dec = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)[..., ::-1]   # libtiff
    assert np.array_equal(dec, expect)
    assert _profile_description(page) == "sRGB built-in"
    assert page.tags[271].value == "phone-isp" and page.tags[272].value == "test phone"
    assert page.tags[274].value == 1 and page.tags[306].value == "2026:11:21 09:08:07"
    exif = page.tags["ExifTag"].value
    assert exif["ExposureTime"] == (1, 250) and exif["ISOSpeedRatings"] == 200
    assert exif["FNumber"][0] / exif["FNumber"][1] == pytest.approx(1.8)
    assert exif["LensModel"] == "lens x" and exif["ColorSpace"] == 1


@pytest.mark.published
@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_applied_like_pillow(orientation):
    img = np.round(display_ramp() * 255).astype(np.uint8)
    pil = Image.fromarray(img)
    pil.getexif()[0x0112] = orientation
    expect = np.asarray(ImageOps.exif_transpose(pil))
    out = create_stage("tiff", bits=8)(Frame(display_ramp(), Domain.DISPLAY_RGB, META.replace(orientation=orientation)))
    assert np.array_equal(_page(bytes(out.data)).asarray(), expect)


@pytest.mark.property
def test_float_tiff_keeps_linear_values_above_one():
    rng = np.random.default_rng(5)
    lin = (rng.random((40, 30, 3)) * 4.0).astype(np.float32)      # scene-linear, up to 4
    out = create_stage("tiff", bits=32)(Frame(lin, Domain.LINEAR_RGB, META))
    page = _page(bytes(out.data))
    assert page.dtype == np.float32 and tuple(page.tags["SampleFormat"].value) == (3, 3, 3)
    back = page.asarray()
    assert np.array_equal(back, lin) and back.max() > 1
    assert _profile_description(page) == "linear sRGB"
    disp = create_stage("tiff", bits=32, compression="deflate")(Frame(display_ramp(), Domain.DISPLAY_RGB, META))
    page = _page(bytes(disp.data))
    assert np.array_equal(page.asarray(), display_ramp()) and _profile_description(page) == "sRGB built-in"


@pytest.mark.property
def test_integer_tiff_of_linear_values_is_refused_at_build():
    with pytest.raises(ConfigError, match="tiff.bits=32"):
        Pipeline([create_stage("tiff", bits=16)], start=Domain.LINEAR_RGB)
    Pipeline([create_stage("tiff", bits=32)], start=Domain.LINEAR_RGB)
    with pytest.raises(ConfigError, match="bits"):
        create_stage("tiff", bits=12)


@pytest.mark.property
def test_without_exif():
    out = create_stage("tiff", exif=False)(Frame(display_ramp(), Domain.DISPLAY_RGB, META))
    page = _page(bytes(out.data))
    assert 34665 not in page.tags and 271 not in page.tags and 34675 in page.tags


@pytest.mark.published
def test_pillow_reads_the_exif_ifd_and_the_profile():
    """A second reader of the Exif IFD written after tifffile's IFD0."""
    out = create_stage("tiff", bits=8)(Frame(display_ramp(), Domain.DISPLAY_RGB, META))
    im = Image.open(io.BytesIO(bytes(out.data)))
    assert np.array_equal(np.asarray(im), np.round(display_ramp() * 255).astype(np.uint8))
    sub = im.getexif().get_ifd(0x8769)
    assert float(sub[0x829A]) == pytest.approx(1 / 250) and sub[0x8827] == 200 and sub[0xA434] == "lens x"
    assert "sRGB" in ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(im.info["icc_profile"])))
