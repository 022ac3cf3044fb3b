"""JPEG encoding with EXIF, the sRGB ICC profile and the orientation applied
to the pixels.

References
----------
* ITU-T T.81 | ISO/IEC 10918-1 (JPEG), via libjpeg-turbo in OpenCV.
* JEITA CP-3451G / CIPA DC-008-2023 (Exif 2.32), 4.5.4: the APP1 segment
  layout; the fields written are :func:`modules.common.encoding.exif_fields`.
* ICC.1:2022, annex B.4: an ICC profile in APP2 segments, each
  ``ICC_PROFILE\\0``, its sequence number and the segment count, then a
  piece of the profile.

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
from isp.stage import StageBase

from modules.common.encoding import apply_orientation, exif_bytes, srgb_icc_profile


def insert_icc(jpeg: bytes, profile: bytes) -> bytes:
    """Put ``profile`` in APP2 ``ICC_PROFILE`` segments right after the
    segments that open the stream (SOI and any APP0/APP1), as ICC.1 annex
    B.4 lays them out: at most 65,519 profile bytes a segment, numbered from 1.

    >>> j = insert_icc(b"\\xff\\xd8\\xff\\xd9", b"abc")
    >>> j[2:4], j[6:18], j[18:20], j[20:23]
    (b'\\xff\\xe2', b'ICC_PROFILE\\x00', b'\\x01\\x01', b'abc')
    """
    if jpeg[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG stream (no SOI marker)")
    step = 0xFFFF - 2 - 14
    pieces = [profile[i:i + step] for i in range(0, len(profile), step)]
    if len(pieces) > 255:
        raise ValueError(f"ICC profile too large for APP2 segments ({len(profile)} bytes)")
    segs = b"".join(b"\xff\xe2" + (len(p) + 16).to_bytes(2, "big") + b"ICC_PROFILE\0"
                    + bytes([k + 1, len(pieces)]) + p for k, p in enumerate(pieces))
    pos = 2
    while jpeg[pos:pos + 2] in (b"\xff\xe0", b"\xff\xe1"):
        pos += 2 + int.from_bytes(jpeg[pos + 2:pos + 4], "big")
    return jpeg[:pos] + segs + jpeg[pos:]


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

    rgb = _to_uint8(rgb)
    if rgb.flags.c_contiguous:
        bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    else:   # a view (turned upright): one copy that also reverses the channels
        bgr = np.ascontiguousarray(rgb[..., ::-1])
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


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    """Display values 0..1 as uint8 (``round(255 |v|)``, saturated) in one
    multithreaded pass; uint8 as it is."""
    if rgb.dtype == np.uint8:
        return rgb
    import cv2

    return cv2.convertScaleAbs(np.ascontiguousarray(rgb), alpha=255.0)


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
    """Encode as JPEG: orientation applied to the pixels, EXIF and the sRGB
    ICC profile written.

    Parameters
    ----------
    quality : int
        1..100 (libjpeg scale).
    subsampling : {"420", "422", "444"}
        Chroma subsampling.
    exif : bool
        Write an Exif APP1 segment (camera, exposure, Orientation = 1).
    icc : bool
        Write the sRGB ICC profile (APP2).
    threads : int
        Bands encoded at once (see :func:`encode_jpeg`); 1 = plain libjpeg.
    """

    name = "jpeg"
    consumes = (Domain.DISPLAY_RGB,)
    produces = Domain.ENCODED

    quality: int = 95
    subsampling: Literal["420", "422", "444"] = "420"
    exif: bool = True
    icc: bool = True
    threads: int = 2

    def __post_init__(self):
        if not 1 <= self.quality <= 100:
            raise ValueError(f"quality must be 1..100, got {self.quality}")
        if not 1 <= self.threads <= 64:
            raise ValueError(f"threads must be 1..64, got {self.threads}")

    def process(self, frame: Frame) -> Frame:
        # to 8 bits first: turning the image upright is then a copy of a quarter of the float data
        img = apply_orientation(_to_uint8(frame.data), frame.meta.orientation)
        data = encode_jpeg(img, self.quality, self.subsampling, self.threads)
        if self.exif:
            data = insert_exif(data, exif_bytes(frame.meta))
        if self.icc:
            data = insert_icc(data, srgb_icc_profile())
        note = f"quality {self.quality}, {self.subsampling}, {len(data) / 1e6:.2f} MB"
        if frame.meta.orientation != 1:
            note += f", orientation {frame.meta.orientation} applied"
        return frame.evolve(np.frombuffer(data, dtype=np.uint8), domain=Domain.ENCODED,
                            stage=self.name, note=note)
