"""PNG stage: files read back by independent decoders (libpng through
OpenCV, Pillow's zlib-based reader), the ICC profile and EXIF read by
Pillow, orientation against Pillow's exif_transpose (kind: published);
16-bit depth, the banded DEFLATE stream and the ICC profile's colour
(kind: property)."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image, ImageCms, ImageOps

from isp import ConfigError, Domain, Frame, create_stage
from modules.png import encode_png
from tests.helpers import display_ramp, encoder_meta

META = encoder_meta()



def _decode_libpng(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)[..., ::-1]


@pytest.mark.published
def test_8_bit_round_trip_icc_and_exif():
    rgb = display_ramp()
    out = create_stage("png")(Frame(rgb, Domain.DISPLAY_RGB, META))
    assert out.domain is Domain.ENCODED
    data = bytes(out.data)
    expect = np.round(rgb * 255).astype(np.uint8)
    assert np.array_equal(_decode_libpng(data), expect)
    im = Image.open(io.BytesIO(data))
    assert im.mode == "RGB" and np.array_equal(np.asarray(im), expect)
    profile = ImageCms.ImageCmsProfile(io.BytesIO(im.info["icc_profile"]))
    assert "sRGB" in ImageCms.getProfileDescription(profile)
    # the embedded profile is sRGB: converting to Pillow's own sRGB changes nothing
    to_srgb = ImageCms.buildTransform(profile, ImageCms.createProfile("sRGB"), "RGB", "RGB")
    assert np.abs(np.asarray(ImageCms.applyTransform(im, to_srgb)).astype(int) - expect).max() <= 1
    exif = im.getexif()
    assert exif[0x010F] == "phone-isp" and exif[0x0110] == "test phone" and exif[0x0112] == 1
    sub = exif.get_ifd(0x8769)
    assert float(sub[0x829A]) == pytest.approx(1 / 250) and sub[0x8827] == 200
    assert float(sub[0x829D]) == pytest.approx(1.8) and sub[0xA434] == "lens x"


@pytest.mark.property
def test_16_bit_holds_more_than_256_levels():
    ramp = np.linspace(0, 1, 4096, dtype=np.float32)
    rgb = np.repeat(np.stack([ramp, ramp[::-1], ramp], axis=1)[None], 4, axis=0)  # (4, 4096, 3)
    out = create_stage("png", bits=16)(Frame(rgb, Domain.DISPLAY_RGB, META))
    dec = _decode_libpng(bytes(out.data))
    assert dec.dtype == np.uint16
    assert np.array_equal(dec, np.round(rgb.astype(np.float64) * 65535).astype(np.uint16))
    assert len(np.unique(dec[..., 0])) == 4096
    assert "16-bit" in out.history[-1].note


@pytest.mark.published
@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_applied_like_pillow(orientation):
    img = np.round(display_ramp() * 255).astype(np.uint8)
    pil = Image.fromarray(img)
    pil.getexif()[0x0112] = orientation
    expect = np.asarray(ImageOps.exif_transpose(pil))
    out = create_stage("png")(Frame(display_ramp(), Domain.DISPLAY_RGB, META.replace(orientation=orientation)))
    assert np.array_equal(_decode_libpng(bytes(out.data)), expect)      # lossless: exactly


@pytest.mark.property
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("threads,level", [(1, 1), (2, 1), (3, 6), (2, 0)])
def test_banded_deflate_is_one_valid_stream(bits, threads, level):
    """Bands deflated apart and joined at sync flushes decode, with libpng and
    with Python's zlib (through Pillow), to the exact samples."""
    rng = np.random.default_rng(bits + threads)
    img = cv2.GaussianBlur(rng.random((301, 203, 3)).astype(np.float32), (0, 0), 2.0)
    img = np.round(img * (2 ** bits - 1)).astype(np.uint8 if bits == 8 else np.uint16)
    data = encode_png(img, threads=threads, level=level)
    assert np.array_equal(_decode_libpng(data), img)
    if bits == 8:
        assert np.array_equal(np.asarray(Image.open(io.BytesIO(data))), img)
    assert data.count(b"IDAT") == max(1, min(threads, 301 // 64))


@pytest.mark.property
def test_grey_image_and_bad_input():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(encode_png(grey)))), grey)
    with pytest.raises(ValueError, match="uint8 or uint16"):
        encode_png(grey.astype(np.float32))
    with pytest.raises(ConfigError, match="level"):
        create_stage("png", level=10)
    with pytest.raises(ConfigError, match="bits"):
        create_stage("png", bits=12)


@pytest.mark.property
def test_values_outside_display_range_saturate():
    rgb = np.array([[[-0.2, 0.5, 1.7], [np.nan, 0.0, 1.0]]], np.float32)
    out = create_stage("png", exif=False)(Frame(rgb, Domain.DISPLAY_RGB, META))
    dec = _decode_libpng(bytes(out.data))
    assert dec.tolist() == [[[0, 128, 255], [0, 0, 255]]]
    assert b"eXIf" not in bytes(out.data) and b"iCCP" in bytes(out.data)
