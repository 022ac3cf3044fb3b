"""What the encoding stages share (modules.common.encoding): the ICC
profiles' colour through LittleCMS (Pillow's ImageCms) against the sRGB
curve of IEC 61966-2-1 (kind: published); EXIF fields and integer
conversion (kind: property)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageCms, TiffImagePlugin

from isp import CameraMeta
from modules.common.encoding import (exif_ifd_bytes, linear_srgb_icc_profile, srgb_icc_profile,
                                     to_integer)
from modules.gamma import srgb_oetf


def _grey_ramp() -> Image.Image:
    levels = np.arange(256, dtype=np.uint8)
    return Image.fromarray(np.repeat(levels[None, :, None], 3, axis=2))


@pytest.mark.published
def test_linear_profile_to_srgb_is_the_srgb_oetf():
    """Linear-sRGB values converted by LittleCMS into the sRGB profile follow
    IEC 61966-2-1's encoding (to 1 of 255), and the primaries are shared:
    pure red, green, blue stay pure."""
    srgb = ImageCms.ImageCmsProfile(io.BytesIO(srgb_icc_profile()))
    linear = ImageCms.ImageCmsProfile(io.BytesIO(linear_srgb_icc_profile()))
    t = ImageCms.buildTransform(linear, srgb, "RGB", "RGB")
    got = np.asarray(ImageCms.applyTransform(_grey_ramp(), t))[0].astype(float)
    want = np.round(srgb_oetf(np.arange(256) / 255.0) * 255)
    assert np.abs(got - want[:, None]).max() <= 1
    prim = Image.fromarray(np.array([[[255, 0, 0], [0, 255, 0], [0, 0, 255]]], np.uint8))
    out = np.asarray(ImageCms.applyTransform(prim, t)).astype(int)
    assert np.abs(out - np.asarray(prim)).max() <= 1


@pytest.mark.published
def test_srgb_profile_is_pillows_srgb():
    srgb = ImageCms.ImageCmsProfile(io.BytesIO(srgb_icc_profile()))
    assert ImageCms.getProfileDescription(srgb).strip() == "sRGB built-in"
    t = ImageCms.buildTransform(srgb, ImageCms.createProfile("sRGB"), "RGB", "RGB")
    assert np.array_equal(np.asarray(ImageCms.applyTransform(_grey_ramp(), t)), np.asarray(_grey_ramp()))


@pytest.mark.property
def test_exif_ifd_at_an_offset_reads_back():
    meta = CameraMeta(exposure_time_s=1 / 60, iso=400.0, lens="L")
    at = 1000
    blob = bytes(at) + exif_ifd_bytes(meta, at)
    ifd = TiffImagePlugin.ImageFileDirectory_v2(prefix=b"II")
    ifd.load(_Seekable(blob, at))
    assert float(ifd[0x829A]) == pytest.approx(1 / 60) and ifd[0x8827] == 400 and ifd[0xA434] == "L"


class _Seekable(io.BytesIO):
    """A file positioned at the IFD, as Pillow's IFD loader expects."""

    def __init__(self, data: bytes, at: int):
        super().__init__(data)
        self.seek(at)


@pytest.mark.property
def test_to_integer_rounds_and_saturates():
    x = np.array([[[-1.0, 0.0, 0.5], [1.0, 2.0, np.nan]]], np.float32)
    assert to_integer(x, 8).tolist() == [[[0, 0, 128], [255, 255, 0]]]
    assert to_integer(x, 16).dtype == np.uint16 and to_integer(x, 16)[0, 1, 0] == 65535
    u8 = np.array([[0, 255]], np.uint8)
    assert to_integer(u8, 8) is u8 and to_integer(u8, 16).tolist() == [[0, 65535]]


@pytest.mark.property
def test_the_srgb_profile_is_the_same_in_every_process():
    """Equal pixels give equal files: the profile carries no creation time."""
    import subprocess
    import sys

    code = "from modules.common.encoding import srgb_icc_profile; print(srgb_icc_profile().hex())"
    runs = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
            for _ in range(2)}
    assert len(runs) == 1
