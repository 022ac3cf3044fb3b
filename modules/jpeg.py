"""JPEG encoding with EXIF and the orientation applied to the pixels.

References
----------
* ITU-T T.81 | ISO/IEC 10918-1 (JPEG), via libjpeg-turbo in OpenCV.
* JEITA CP-3451G / CIPA DC-008-2023 (Exif 2.32), APP1 segment layout and the
  Orientation tag (0x0112): 1 = normal ... 8 = rotated 270° CW.

The pixels are turned upright before encoding and the EXIF Orientation is
written as 1, so every viewer shows the same image (viewers that ignore
EXIF orientation are common). The stage returns the file's bytes; writing
them (atomically) is the caller's job (:func:`isp.io.files.write_output`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.frame import Domain, Frame
from isp.meta import CameraMeta
from isp.stage import StageBase


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


def exif_bytes(meta: CameraMeta, software: str = "phone-isp") -> bytes:
    """An Exif APP1 payload (starting ``Exif\\0\\0``) with the camera and
    capture fields of ``meta``; Orientation = 1 (pixels already upright)."""
    from PIL import Image, TiffImagePlugin

    exif = Image.Exif()
    if meta.make:
        exif[0x010F] = meta.make
    if meta.model or meta.unique_camera_model:
        exif[0x0110] = meta.model or meta.unique_camera_model
    exif[0x0131] = software
    exif[0x0112] = 1
    if meta.datetime:
        exif[0x0132] = meta.datetime
    sub = {}
    if meta.exposure_time_s:
        sub[0x829A] = TiffImagePlugin.IFDRational(meta.exposure_time_s)
    if meta.f_number:
        sub[0x829D] = TiffImagePlugin.IFDRational(meta.f_number)
    if meta.iso:
        sub[0x8827] = int(round(meta.iso))
    if meta.focal_length_mm:
        sub[0x920A] = TiffImagePlugin.IFDRational(meta.focal_length_mm)
    if meta.datetime:
        sub[0x9003] = meta.datetime
    if meta.lens:
        sub[0xA434] = meta.lens
    sub[0xA001] = 1  # ColorSpace: sRGB
    if sub:
        ifd = exif.get_ifd(0x8769)
        ifd.update(sub)
    return exif.tobytes()


def insert_exif(jpeg: bytes, payload: bytes) -> bytes:
    """Put an APP1 Exif segment right after SOI, dropping a JFIF APP0
    (Exif files carry APP1 first; JFIF and Exif headers conflict)."""
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG stream (no SOI marker)")
    if len(payload) + 2 > 0xFFFF:
        raise ValueError(f"Exif payload too large ({len(payload)} bytes)")
    rest = jpeg[2:]
    if rest[:2] == b"\xff\xe0":
        n = int.from_bytes(rest[2:4], "big")
        rest = rest[2 + n:]
    seg = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    return jpeg[:2] + seg + rest


_SAMPLING = {"420": (16, 16), "422": (8, 16), "444": (8, 8)}  # MCU (rows, cols)


def _cv_params(quality: int, subsampling: str, restart: int = 0) -> list[int]:
    import cv2

    sampling = {"420": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
                "422": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
                "444": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}[subsampling]
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR, sampling]
    if restart:
        params += [cv2.IMWRITE_JPEG_RST_INTERVAL, int(restart)]
    return params


def _segments(jpeg: bytes) -> tuple[int, int, int]:
    """(offset of the SOF0 height field, start of the entropy-coded data,
    offset of EOI) of a baseline JPEG from libjpeg."""
    pos, sof = 2, -1
    while pos + 4 <= len(jpeg):
        if jpeg[pos] != 0xFF:
            raise ValueError(f"JPEG marker expected at byte {pos}")
        marker = jpeg[pos + 1]
        length = int.from_bytes(jpeg[pos + 2:pos + 4], "big")
        if marker in (0xC0, 0xC1, 0xC2):
            sof = pos + 5
        if marker == 0xDA:  # SOS: the scan data follows its header
            end = jpeg.rindex(b"\xff\xd9")
            return sof, pos + 2 + length, end
        pos += 2 + length
    raise ValueError("no SOS marker in the JPEG stream")


def encode_jpeg(rgb: np.ndarray, quality: int = 95, subsampling: str = "420",
                threads: int = 2) -> bytes:
    """Encode display RGB (float 0..1 or uint8) as baseline JPEG bytes.

    Parameters
    ----------
    rgb : (H, W, 3) ndarray, float32 in [0, 1] or uint8
    quality : int, 1..100
    subsampling : {"420", "422", "444"}
    threads : int
        Encode this many horizontal bands at once (on a persistent pool of
        as many threads, :func:`isp.runtime.executor.shared_threads`) and
        join them.

    Notes
    -----
    libjpeg encodes on one core. With ``threads > 1`` the image is cut into
    bands at MCU-row boundaries, each band encoded with a restart marker
    after every MCU row (ITU-T T.81, B.2.4.4: restart markers reset the DC
    predictors, so a band's entropy-coded data does not depend on the band
    before it), and the bands' scan data are joined with their restart
    markers renumbered (RST0–7 cycle). The result is the single baseline
    JPEG one encoder would write with the same restart interval: identical
    decoded pixels, ~2 bytes more per MCU row than without restarts.
    """
    import cv2

    if rgb.dtype != np.uint8:
        # rounds and saturates to 0..255 in one multithreaded pass
        rgb = cv2.convertScaleAbs(np.ascontiguousarray(rgb), alpha=255.0)
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)
    h, w = bgr.shape[:2]
    mcu_h, mcu_w = _SAMPLING[subsampling]
    mcu_rows = -(-h // mcu_h)
    threads = max(1, min(int(threads), mcu_rows // 4))
    if threads == 1:
        ok, buf = cv2.imencode(".jpg", bgr, _cv_params(quality, subsampling))
        if not ok:
            raise RuntimeError("OpenCV failed to encode the JPEG")
        return buf.tobytes()

    params = _cv_params(quality, subsampling, restart=-(-w // mcu_w))
    cuts = [round(k * mcu_rows / threads) * mcu_h for k in range(threads)] + [h]
    bands = [bgr[a:b] for a, b in zip(cuts, cuts[1:])]

    def encode(band):
        ok, buf = cv2.imencode(".jpg", band, params)
        if not ok:
            raise RuntimeError("OpenCV failed to encode the JPEG")
        return buf.tobytes()

    from isp.runtime.executor import shared_threads

    parts = shared_threads(threads).map(encode, bands)  # imencode releases the GIL
    sof, start, end = _segments(parts[0])
    out = bytearray(parts[0][:start])
    out[sof:sof + 2] = h.to_bytes(2, "big")
    rows_before = 0
    for k, part in enumerate(parts):
        s0, s1, e = _segments(part) if k else (sof, start, end)
        scan = part[s1:e]
        if rows_before:
            out += bytes([0xFF, 0xD0 + (rows_before - 1) % 8])  # the marker ending the last band
            scan = _renumber_restarts(scan, rows_before)
        out += scan
        rows_before += -(-(cuts[k + 1] - cuts[k]) // mcu_h)
    out += b"\xff\xd9"
    return bytes(out)


def _renumber_restarts(scan: bytes, offset: int) -> bytes:
    """Shift every RSTn marker of entropy-coded data by ``offset`` (mod 8).
    In scan data 0xFF is always followed by 0x00 (stuffing) or a marker, so
    a restart marker is exactly a byte pair FF D0–D7."""
    if offset % 8 == 0:
        return scan
    a = np.frombuffer(scan, np.uint8).copy()
    idx = np.flatnonzero((a[:-1] == 0xFF) & (a[1:] >= 0xD0) & (a[1:] <= 0xD7)) + 1
    a[idx] = 0xD0 + (a[idx] - 0xD0 + offset) % 8
    return a.tobytes()


@dataclass(frozen=True)
class Jpeg(StageBase):
    """Encode as JPEG: orientation applied to the pixels, EXIF written.

    Parameters
    ----------
    quality : int
        1..100 (libjpeg scale).
    subsampling : {"420", "422", "444"}
        Chroma subsampling.
    exif : bool
        Write an Exif APP1 segment (camera, exposure, Orientation = 1).
    threads : int
        Bands encoded at once (see :func:`encode_jpeg`); 1 = plain libjpeg.
    """

    name = "jpeg"
    consumes = (Domain.DISPLAY_RGB,)
    produces = Domain.ENCODED

    quality: int = 95
    subsampling: Literal["420", "422", "444"] = "420"
    exif: bool = True
    threads: int = 2

    def __post_init__(self):
        if not 1 <= self.quality <= 100:
            raise ValueError(f"quality must be 1..100, got {self.quality}")
        if not 1 <= self.threads <= 64:
            raise ValueError(f"threads must be 1..64, got {self.threads}")

    def process(self, frame: Frame) -> Frame:
        img = apply_orientation(frame.data, frame.meta.orientation)
        data = encode_jpeg(img, self.quality, self.subsampling, self.threads)
        if self.exif:
            data = insert_exif(data, exif_bytes(frame.meta))
        note = f"quality {self.quality}, {self.subsampling}, {len(data) / 1e6:.2f} MB"
        if frame.meta.orientation != 1:
            note += f", orientation {frame.meta.orientation} applied"
        return frame.evolve(np.frombuffer(data, dtype=np.uint8), domain=Domain.ENCODED,
                            stage=self.name, note=note)
