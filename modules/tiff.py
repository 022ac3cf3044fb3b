"""TIFF encoding: 8/16-bit integer display RGB, or 32-bit float (display
or scene-linear RGB), with the ICC profile, EXIF and the orientation
applied to the pixels.

References
----------
* TIFF Revision 6.0 (Adobe, 1992): baseline RGB (PhotometricInterpretation
  2), Compression 1 (none) or 8 (Deflate, from the TIFF Technical Note /
  Adobe Photoshop TIFF supplement) with Predictor 2 (horizontal
  differencing, section 14) for integer samples, SampleFormat 3 (IEEE
  float, section 19) for 32-bit samples; Make, Model, Orientation,
  Software, DateTime in IFD0.
* ICC.1:2022, annex B.4: the profile as tag 34675 (InterColorProfile).
* Exif 2.32 (CIPA DC-008-2023), 4.6.3: the Exif IFD pointer (tag 34665) in
  IFD0.

Float TIFFs
-----------
``bits = 32`` writes the frame's values as float32, unclipped. A
``display_rgb`` frame is written with the sRGB profile; a ``linear_rgb``
frame (the linear look stopped before its ``gamma`` stage) with a
linear-sRGB profile, holding scene-linear values that may exceed 1. From
the command line, ``isp process x.dng --look linear -o x.tif --set
tiff.bits=32`` writes the latter: a 32-bit float TIFF right after a
``gamma`` stage leaves that stage out. 8- and 16-bit TIFFs hold display
values only.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.errors import ConfigError
from isp.frame import Domain, Frame
from isp.meta import CameraMeta
from isp.stage import StageBase

from modules.common.encoding import (EXIF_IFD, apply_orientation, exif_fields, exif_ifd_bytes,
                                     linear_srgb_icc_profile, srgb_icc_profile, to_integer)

#: a private tag number that holds the Exif IFD pointer's place while
#: tifffile writes the file (tifffile does not write tag 34665); no tag lies
#: between it and 34665, so the IFD stays sorted when it is renamed
_EXIF_PLACEHOLDER = EXIF_IFD - 1


def _ifd0_tags(meta: CameraMeta) -> list[tuple]:
    ifd0, _ = exif_fields(meta)
    tags = [(tag, "s", 0, ifd0[tag], True) for tag in (0x010F, 0x0110, 0x0132) if tag in ifd0]
    tags.append((0x0112, "H", 1, 1, True))
    return tags


def _attach_exif_ifd(buf: io.BytesIO, meta: CameraMeta) -> None:
    """Append the Exif IFD of ``meta`` to a little-endian classic TIFF being
    written in ``buf`` and point IFD0's placeholder entry at it, renamed to
    tag 34665 (in place: a 12 MP file is not copied)."""
    head = buf.getbuffer()
    try:
        first = struct.unpack_from("<I", head, 4)[0]
        n = struct.unpack_from("<H", head, first)[0]
        entries = [first + 2 + 12 * i for i in range(n)]
        entry = next((e for e in entries if struct.unpack_from("<H", head, e)[0] == _EXIF_PLACEHOLDER), None)
    finally:
        head.release()
    if entry is None:
        raise RuntimeError("the Exif placeholder tag is missing from the TIFF written")
    end = buf.seek(0, io.SEEK_END)
    at = end + (-end % 4)
    buf.write(bytes(at - end) + exif_ifd_bytes(meta, at))
    buf.seek(entry)
    buf.write(struct.pack("<HHII", EXIF_IFD, 4, 1, at))


def encode_tiff(img: np.ndarray, *, icc: bytes | None = None, meta: CameraMeta | None = None,
                compression: str = "none", threads: int = 2) -> bytes:
    """Encode an RGB image as TIFF bytes (little-endian, classic TIFF).

    Parameters
    ----------
    img : (H, W, 3) ndarray, uint8, uint16 or float32
        Samples as they go into the file.
    icc : bytes, optional
        An ICC profile (tag 34675).
    meta : CameraMeta, optional
        Its camera fields go to IFD0 (Make, Model, DateTime, Orientation = 1)
        and an Exif IFD (exposure, lens, ColorSpace); none: no EXIF.
    compression : {"none", "deflate"}
        Deflate uses horizontal differencing (Predictor 2) on integer
        samples and none on floats; strips are compressed on ``threads``
        threads. About 0.8× the size of a 16-bit photograph, and seconds
        of work at 12 MP (none: a fraction of a second).
    threads : int

    Returns
    -------
    bytes
        The TIFF file.

    >>> t = encode_tiff(np.zeros((2, 3, 3), np.uint16))
    >>> t[:4]
    b'II*\\x00'
    """
    import tifffile

    if img.dtype not in (np.uint8, np.uint16, np.float32):
        raise ValueError(f"TIFF samples must be uint8, uint16 or float32, got {img.dtype}")
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
    if compression not in ("none", "deflate"):
        raise ValueError(f"compression must be 'none' or 'deflate', got {compression!r}")
    kwargs: dict = {}
    if compression == "deflate":
        kwargs = {"compression": "zlib", "predictor": img.dtype != np.float32,
                  "rowsperstrip": max(16, -(-img.shape[0] // (4 * max(1, threads)))),
                  "maxworkers": max(1, threads)}
    extratags = []
    if meta is not None:
        extratags = _ifd0_tags(meta) + [(_EXIF_PLACEHOLDER, "I", 1, 0, True)]
    buf = io.BytesIO()
    tifffile.imwrite(buf, np.ascontiguousarray(img), photometric="rgb", byteorder="<", bigtiff=False,
                     metadata=None, software="phone-isp", iccprofile=icc, extratags=extratags, **kwargs)
    if meta is not None:
        _attach_exif_ifd(buf, meta)
    return buf.getvalue()


@dataclass(frozen=True)
class Tiff(StageBase):
    """Encode as TIFF: orientation applied to the pixels, the ICC profile and
    EXIF embedded.

    Parameters
    ----------
    bits : {8, 16, 32}
        8 or 16: unsigned integers of display values (clipped to [0, 1]);
        32: float32 values as they are (``display_rgb`` with the sRGB
        profile, ``linear_rgb`` with a linear-sRGB profile; see the module
        notes). ``--set tiff.bits=32`` on the command line.
    compression : {"none", "deflate"}
    exif : bool
        Write EXIF (IFD0 camera fields and an Exif IFD; Orientation = 1).
    threads : int
        Strips compressed at once (``deflate``).
    """

    name = "tiff"
    consumes = (Domain.DISPLAY_RGB, Domain.LINEAR_RGB)
    produces = Domain.ENCODED

    bits: Literal[8, 16, 32] = 16
    compression: Literal["none", "deflate"] = "none"
    exif: bool = True
    threads: int = 2

    def __post_init__(self):
        if not 1 <= self.threads <= 64:
            raise ValueError(f"threads must be 1..64, got {self.threads}")

    def check(self, domain: Domain) -> None:
        if domain is Domain.LINEAR_RGB and self.bits != 32:
            raise ConfigError(f"a {self.bits}-bit TIFF holds display values: put gamma before it, "
                              "or set tiff.bits=32 for a float TIFF of the linear values")

    def process(self, frame: Frame) -> Frame:
        self.check(frame.domain)
        linear = frame.domain is Domain.LINEAR_RGB
        if self.bits == 32:
            img = np.ascontiguousarray(apply_orientation(frame.data, frame.meta.orientation), dtype=np.float32)
        else:   # to integers first: turning them upright copies half the bytes of the floats
            img = apply_orientation(to_integer(frame.data, self.bits), frame.meta.orientation)
        icc = linear_srgb_icc_profile() if linear else srgb_icc_profile()
        data = encode_tiff(img, icc=icc, meta=frame.meta if self.exif else None,
                           compression=self.compression, threads=self.threads)
        kind = "float" if self.bits == 32 else "integer"
        note = (f"{self.bits}-bit {kind}, {'linear sRGB' if linear else 'sRGB'} profile, "
                f"{len(data) / 1e6:.2f} MB")
        if frame.meta.orientation != 1:
            note += f", orientation {frame.meta.orientation} applied"
        return frame.evolve(np.frombuffer(data, dtype=np.uint8), domain=Domain.ENCODED,
                            stage=self.name, note=note)
