"""What every encoding stage (``jpeg``, ``png``, ``tiff``) writes besides the
pixels: the orientation applied to them, the EXIF fields, the ICC profile,
and the float-to-integer conversion.

References
----------
* JEITA CP-3451G / CIPA DC-008-2023 (Exif 2.32): the IFD0 fields Make
  (0x010F), Model (0x0110), Orientation (0x0112: 1 = normal ... 8 = rotated
  270° CW), Software (0x0131), DateTime (0x0132), and the Exif IFD (0x8769)
  with ExposureTime, FNumber, ISOSpeedRatings, DateTimeOriginal,
  FocalLength, LensModel and ColorSpace (1 = sRGB).
* IEC 61966-2-1:1999 (sRGB) and ICC.1:2022 (profile format 4.4): the sRGB
  profile is LittleCMS's built-in one (made by Pillow's
  ``ImageCms.createProfile("sRGB")``: the sRGB primaries adapted to the
  D50 connection space by Bradford, the sRGB curve as a parametric curve);
  the linear-sRGB profile is the same profile with identity tone curves.
  Both are made at run time; no profile file is shipped.

The pixels are turned upright before encoding and the EXIF Orientation is
written as 1, so every viewer shows the same image (viewers that ignore
EXIF orientation are common).
"""

from __future__ import annotations

import hashlib
import struct
from functools import lru_cache

import numpy as np

from isp.meta import CameraMeta

#: EXIF tag numbers this module writes
EXIF_IFD = 0x8769


def apply_orientation(img: np.ndarray, orientation: int) -> np.ndarray:
    """Turn an image stored with EXIF ``orientation`` (1..8) upright.

    Parameters
    ----------
    img : (H, W, ...) ndarray
    orientation : int

    Returns
    -------
    ndarray (a view where possible): (H, W, ...) for 1–4, (W, H, ...) for 5–8.

    >>> apply_orientation(np.arange(6).reshape(2, 3), 6)   # 90° CW
    array([[3, 0],
           [4, 1],
           [5, 2]])
    """
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: np.swapaxes(a, 0, 1),
        6: lambda a: np.swapaxes(a, 0, 1)[:, ::-1],
        7: lambda a: np.swapaxes(a, 0, 1)[::-1, ::-1],
        8: lambda a: np.swapaxes(a, 0, 1)[::-1],
    }
    if orientation not in ops:
        raise ValueError(f"orientation must be 1..8, got {orientation}")
    return ops[orientation](img)


def exif_fields(meta: CameraMeta, software: str = "phone-isp") -> tuple[dict, dict]:
    """The EXIF fields of ``meta``: ``(ifd0, exif_ifd)``, each ``{tag: value}``
    with Pillow's value types (str, int, ``IFDRational``); Orientation = 1
    (the pixels are already upright), ColorSpace = 1 (sRGB).

    >>> ifd0, sub = exif_fields(CameraMeta(make="X", iso=100.0))
    >>> ifd0[0x010F], ifd0[0x0112], sub[0x8827], sub[0xA001]
    ('X', 1, 100, 1)
    """
    from PIL import TiffImagePlugin

    ifd0: dict = {}
    if meta.make:
        ifd0[0x010F] = meta.make
    if meta.model or meta.unique_camera_model:
        ifd0[0x0110] = meta.model or meta.unique_camera_model
    ifd0[0x0112] = 1
    ifd0[0x0131] = software
    if meta.datetime:
        ifd0[0x0132] = meta.datetime
    sub: dict = {}
    if meta.exposure_time_s:
        sub[0x829A] = TiffImagePlugin.IFDRational(meta.exposure_time_s)
    if meta.f_number:
        sub[0x829D] = TiffImagePlugin.IFDRational(meta.f_number)
    if meta.iso:
        sub[0x8827] = int(round(meta.iso))
    if meta.datetime:
        sub[0x9003] = meta.datetime
    if meta.focal_length_mm:
        sub[0x920A] = TiffImagePlugin.IFDRational(meta.focal_length_mm)
    if meta.lens:
        sub[0xA434] = meta.lens
    sub[0xA001] = 1
    return ifd0, sub


def exif_bytes(meta: CameraMeta, software: str = "phone-isp") -> bytes:
    """An Exif payload as JPEG's APP1 segment carries it: ``Exif\\0\\0`` and a
    TIFF structure (IFD0 + Exif IFD) of :func:`exif_fields`. PNG's ``eXIf``
    chunk holds the same bytes without the 6-byte prefix.

    >>> exif_bytes(CameraMeta(make="X"))[:6]
    b'Exif\\x00\\x00'
    """
    from PIL import Image

    ifd0, sub = exif_fields(meta, software)
    exif = Image.Exif()
    for tag, value in ifd0.items():
        exif[tag] = value
    exif.get_ifd(EXIF_IFD).update(sub)
    return exif.tobytes()


def exif_ifd_bytes(meta: CameraMeta, offset: int) -> bytes:
    """The Exif IFD of ``meta`` alone (little-endian, as TIFF stores an IFD:
    entry count, 12-byte entries, next-IFD pointer 0, then the values that
    do not fit in an entry), laid out to start at byte ``offset`` of a file.

    >>> b = exif_ifd_bytes(CameraMeta(iso=200.0), 1000)
    >>> int.from_bytes(b[:2], "little")       # ISOSpeedRatings, ColorSpace
    2
    """
    from PIL import TiffImagePlugin

    _, sub = exif_fields(meta)
    ifd = TiffImagePlugin.ImageFileDirectory_v2(prefix=b"II")
    for tag, value in sub.items():
        ifd[tag] = value
    return ifd.tobytes(offset)


# -- ICC profiles -------------------------------------------------------------

def _mluc(text: str) -> bytes:
    """An ICC ``multiLocalizedUnicodeType`` holding one en-US string (ICC.1, 10.15)."""
    s = text.encode("utf-16-be")
    return b"mluc" + bytes(4) + struct.pack(">II", 1, 12) + b"enUS" + struct.pack(">II", len(s), 28) + s


def _with_profile_id(profile: bytearray) -> bytes:
    """The profile with its size field and its MD5 profile ID (ICC.1, 7.2.18:
    the digest of the profile with flags, rendering intent and ID zeroed)."""
    struct.pack_into(">I", profile, 0, len(profile))
    tmp = bytearray(profile)
    tmp[44:48] = bytes(4)
    tmp[64:68] = bytes(4)
    tmp[84:100] = bytes(16)
    profile[84:100] = hashlib.md5(bytes(tmp)).digest()
    return bytes(profile)


@lru_cache(maxsize=1)
def srgb_icc_profile() -> bytes:
    """The sRGB (IEC 61966-2-1) ICC profile: LittleCMS's built-in sRGB
    profile, version 4.4, 588 bytes.

    >>> from PIL import ImageCms; import io
    >>> ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(srgb_icc_profile()))).strip()
    'sRGB built-in'
    """
    from PIL import ImageCms

    profile = bytearray(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    # LittleCMS stamps the creation time (ICC.1, 7.2.1, bytes 24-35); a fixed
    # one makes equal pixels give equal files, run after run.
    struct.pack_into(">6H", profile, 24, 1999, 10, 18, 0, 0, 0)
    return _with_profile_id(profile)


@lru_cache(maxsize=1)
def linear_srgb_icc_profile() -> bytes:
    """A linear-sRGB ICC profile: :func:`srgb_icc_profile` with every tone
    curve (rTRC, gTRC, bTRC) replaced by the identity (a ``curv`` of no
    entries, ICC.1 10.6) and the description "linear sRGB"; for float
    files holding scene-linear values on the sRGB primaries (D65 white).

    >>> from PIL import ImageCms; import io
    >>> ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(linear_srgb_icc_profile()))).strip()
    'linear sRGB'
    """
    src = srgb_icc_profile()
    n = struct.unpack(">I", src[128:132])[0]
    tags = [struct.unpack(">4sII", src[132 + 12 * i:144 + 12 * i]) for i in range(n)]
    out = bytearray(src)
    out += bytes(-len(out) % 4)
    curve_at = len(out)
    out += b"curv" + bytes(4) + struct.pack(">I", 0)
    desc = _mluc("linear sRGB")
    desc_at = len(out)
    out += desc + bytes(-len(desc) % 4)
    for i, (sig, off, size) in enumerate(tags):
        if sig in (b"rTRC", b"gTRC", b"bTRC"):
            off, size = curve_at, 12
        elif sig == b"desc":
            off, size = desc_at, len(desc)
        struct.pack_into(">4sII", out, 132 + 12 * i, sig, off, size)
    return _with_profile_id(out)


# -- sample values --------------------------------------------------------------

def to_integer(rgb: np.ndarray, bits: int) -> np.ndarray:
    """Display values in [0, 1] as unsigned integers of ``bits`` (8 or 16):
    ``round(v × (2^bits − 1))``, saturated (values outside [0, 1] clip, NaN
    gives 0). Integer input of the right type is returned as it is.

    Parameters
    ----------
    rgb : (H, W, C) or (H, W) ndarray, float (0..1) or uint8/uint16
    bits : {8, 16}

    Returns
    -------
    ndarray of rgb's shape, uint8 or uint16.

    >>> to_integer(np.array([[[0.0, 0.5, 1.2]]], np.float32), 16)
    array([[[    0, 32768, 65535]]], dtype=uint16)
    """
    import cv2

    dtype = {8: np.uint8, 16: np.uint16}[bits]
    if rgb.dtype == dtype:
        return rgb
    if rgb.dtype in (np.uint8, np.uint16):
        scale = (2 ** bits - 1) / (2 ** (8 * rgb.itemsize) - 1)
        return np.round(rgb * scale).astype(dtype)
    x = np.ascontiguousarray(rgb, dtype=np.float32)
    # one multithreaded pass that scales, rounds and saturates; reshaped to one
    # channel because OpenCV's scalar would scale only the first of three
    out = cv2.multiply(x.reshape(x.shape[0], -1), float(2 ** bits - 1),
                       dtype=cv2.CV_8U if bits == 8 else cv2.CV_16U)
    return out.reshape(x.shape)
