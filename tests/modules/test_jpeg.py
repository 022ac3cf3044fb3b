"""JPEG stage: EXIF and the ICC profile read back by an independent decoder (Pillow), orientation
against Pillow's exif_transpose (kind: published), fidelity and banded
encoding (kind: property)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageOps

from isp import Domain, Frame, create_stage
from modules.common.encoding import apply_orientation
from tests.helpers import encoder_meta


def _display(h=48, w=64):
    y, x = np.mgrid[0:h, 0:w]
    rgb = np.stack([x / w, y / h, 0.5 + 0 * x], axis=2).astype(np.float32)
    rgb[:8, :8] = [1, 0, 0]   # a red top-left corner marks orientation
    return rgb


META = encoder_meta()


@pytest.mark.published
def test_exif_written_and_readable():
    f = Frame(_display(), Domain.DISPLAY_RGB, META)
    out = create_stage("jpeg", quality=90)(f)
    assert out.domain is Domain.ENCODED
    im = Image.open(io.BytesIO(bytes(out.data)))
    exif = im.getexif()
    assert exif[0x010F] == "phone-isp" and exif[0x0110] == "test phone"
    assert exif[0x0112] == 1                         # orientation applied to the pixels
    sub = exif.get_ifd(0x8769)
    assert float(sub[0x829A]) == pytest.approx(1 / 250)
    assert float(sub[0x829D]) == pytest.approx(1.8) and sub[0x8827] == 200
    assert float(sub[0x920A]) == pytest.approx(4.2) and sub[0xA434] == "lens x"


@pytest.mark.published
def test_icc_profile_in_app2():
    """Pillow reassembles the APP2 ICC_PROFILE segments into the sRGB profile;
    ``icc=False`` leaves them out."""
    from PIL import ImageCms

    from modules.common.encoding import srgb_icc_profile

    f = Frame(_display(), Domain.DISPLAY_RGB, META)
    data = bytes(create_stage("jpeg")(f).data)
    im = Image.open(io.BytesIO(data))
    assert im.info["icc_profile"] == srgb_icc_profile()
    assert "sRGB" in ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(im.info["icc_profile"])))
    assert im.getexif()[0x010F] == "phone-isp"          # APP1 still read
    bare = Image.open(io.BytesIO(bytes(create_stage("jpeg", icc=False)(f).data)))
    assert "icc_profile" not in bare.info


@pytest.mark.property
def test_large_icc_profile_spans_segments():
    from modules.jpeg import insert_icc

    profile = bytes(range(256)) * 600                     # 153,600 bytes: three segments
    data = insert_icc(bytes(create_stage("jpeg", exif=False, icc=False)(Frame(_display(), Domain.DISPLAY_RGB, META)).data),
                      profile)
    im = Image.open(io.BytesIO(data))
    assert im.info["icc_profile"] == profile and data.count(b"ICC_PROFILE\0") == 3


@pytest.mark.published
@pytest.mark.parametrize("orientation", range(1, 9))
def test_orientation_applied_like_pillow(orientation):
    img = (_display() * 255).round().astype(np.uint8)
    pil = Image.fromarray(img)
    pil.getexif()[0x0112] = orientation
    expect = np.asarray(ImageOps.exif_transpose(pil))
    assert np.array_equal(apply_orientation(img, orientation), expect)
    out = create_stage("jpeg", quality=100, subsampling="444")(
        Frame(_display(), Domain.DISPLAY_RGB, META.replace(orientation=orientation)))
    dec = np.asarray(Image.open(io.BytesIO(bytes(out.data))))
    assert dec.shape == expect.shape
    assert np.abs(dec.astype(int) - expect).mean() < 2.0


@pytest.mark.property
def test_quality_and_fidelity():
    rgb = _display(256, 256)
    sizes = []
    for q in (50, 95):
        out = create_stage("jpeg", quality=q)(Frame(rgb, Domain.DISPLAY_RGB, META))
        sizes.append(out.data.size)
        dec = np.asarray(Image.open(io.BytesIO(bytes(out.data)))).astype(np.float64) / 255
        psnr = 10 * np.log10(1 / np.mean((dec - rgb) ** 2))
        assert psnr > (30 if q == 50 else 38)
    assert sizes[0] < sizes[1]


@pytest.mark.property
@pytest.mark.parametrize("shape,subsampling", [((300, 200), "420"), ((257, 333), "444"), ((130, 96), "422")])
@pytest.mark.parametrize("threads", [2, 3])
def test_banded_encoding_is_the_single_encoder_stream(shape, subsampling, threads):
    """Bands joined at restart markers give byte for byte the stream one
    libjpeg writes with the same restart interval (reference: OpenCV's own
    single-call encode)."""
    import cv2

    from modules.jpeg import _SAMPLING, _cv_params, encode_jpeg

    rng = np.random.default_rng(3)
    rgb = cv2.GaussianBlur(rng.random((*shape, 3)).astype(np.float32), (0, 0), 1.5)
    ours = encode_jpeg(rgb, 90, subsampling, threads=threads)
    bgr = cv2.cvtColor(cv2.convertScaleAbs(rgb, alpha=255.0), cv2.COLOR_RGB2BGR)
    restart = -(-shape[1] // _SAMPLING[subsampling][1])
    ok, ref = cv2.imencode(".jpg", bgr, _cv_params(90, subsampling, restart))
    assert ours == ref.tobytes()
    dec = np.asarray(Image.open(io.BytesIO(ours)))      # an independent decoder reads it
    assert dec.shape == (*shape, 3)
