"""PNG encoding, 8 or 16 bits per sample, with the sRGB ICC profile, EXIF
and the orientation applied to the pixels.

References
----------
* ISO/IEC 15948:2004 and PNG Third Edition (W3C, 2025): the chunk layout
  (length, type, data, CRC-32), IHDR, ``iCCP`` (11.3.3.3: a profile name,
  compression method 0, the zlib-compressed profile), ``eXIf`` (11.3.6.3:
  the Exif TIFF structure without JPEG's ``Exif\\0\\0`` prefix), IDAT (a
  zlib stream of the filtered scanlines), IEND; filter type 2 "Up" (9.2);
  samples of 16 bits stored big-endian (7.1).
* RFC 1950 (zlib) and RFC 1951 (DEFLATE): a zlib stream is a 2-byte header,
  DEFLATE blocks and the Adler-32 of the uncompressed data.

Notes
-----
Every scanline is filtered with "Up" (each byte minus the byte above it),
one vectorised subtraction for the whole image; on photographs it
compresses about as well as libpng's adaptive choice at its fast levels.
The filtered rows are cut into ``threads`` bands deflated at once, each
band ended by a sync flush (RFC 1951 3.2.4: an empty stored block brings
the stream to a byte boundary) except the last, which is final; the bands'
DEFLATE data laid end to end are one valid DEFLATE stream, framed by one
zlib header and the Adler-32 of all the rows (the approach of pigz). A
band cannot refer back into the band before it, which costs well under 1 %
of the size.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.frame import Domain, Frame
from isp.stage import StageBase

from modules.common.encoding import apply_orientation, exif_bytes, srgb_icc_profile, to_integer

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: the name of the embedded profile (the ``iCCP`` chunk's keyword)
ICC_NAME = b"sRGB IEC61966-2.1"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _deflate_band(band: np.ndarray, level: int, last: bool) -> bytes:
    strategy = zlib.Z_RLE if level <= 1 else zlib.Z_DEFAULT_STRATEGY
    c = zlib.compressobj(level, zlib.DEFLATED, -15, 9, strategy)
    return c.compress(band) + c.flush(zlib.Z_FINISH if last else zlib.Z_SYNC_FLUSH)


def encode_png(img: np.ndarray, *, icc: bytes | None = None, exif: bytes | None = None,
               level: int = 1, threads: int = 2) -> bytes:
    """Encode an RGB or grey image as PNG bytes.

    Parameters
    ----------
    img : (H, W, 3) or (H, W) ndarray, uint8 or uint16
        Samples as they go into the file (8 or 16 bits per sample).
    icc : bytes, optional
        An ICC profile, written as the ``iCCP`` chunk (named
        :data:`ICC_NAME`).
    exif : bytes, optional
        An Exif payload (with or without the ``Exif\\0\\0`` prefix), written
        as the ``eXIf`` chunk.
    level : int
        zlib level, 0..9. 1 (default) deflates with run-length matches only
        (zlib's ``Z_RLE`` strategy), the fastest; 2–9 search matches in full.
    threads : int
        Bands deflated at once (on :func:`isp.runtime.executor.shared_threads`;
        zlib releases the GIL).

    Returns
    -------
    bytes
        The PNG file.

    >>> png = encode_png(np.zeros((2, 3, 3), np.uint8))
    >>> png[:8], png[12:16], struct.unpack(">II", png[16:24])
    (b'\\x89PNG\\r\\n\\x1a\\n', b'IHDR', (3, 2))
    """
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG samples must be uint8 or uint16, got {img.dtype}")
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"expected an (H, W, 3) or (H, W) image, got shape {img.shape}")
    if not 0 <= level <= 9:
        raise ValueError(f"level must be 0..9, got {level}")
    h, w = img.shape[:2]
    bits = 8 * img.itemsize
    colour_type = 2 if img.ndim == 3 else 0
    rows = np.ascontiguousarray(img, dtype=">u2" if bits == 16 else np.uint8).view(np.uint8).reshape(h, -1)
    filtered = np.empty((h, rows.shape[1] + 1), np.uint8)
    filtered[:, 0] = 2  # filter type Up; the row above the first counts as zeros
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])

    threads = max(1, min(int(threads), h // 64 or 1))
    cuts = [round(k * h / threads) for k in range(threads + 1)]
    bands = [(filtered[a:b], level, b == h) for a, b in zip(cuts, cuts[1:])]
    if threads == 1:
        parts = [_deflate_band(*bands[0])]
    else:
        from isp.runtime.executor import shared_threads

        parts = shared_threads(threads).map(lambda job: _deflate_band(*job), bands)
    adler = zlib.adler32(filtered)

    out = [_SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bits, colour_type, 0, 0, 0))]
    if icc is not None:
        out.append(_chunk(b"iCCP", ICC_NAME + b"\0\0" + zlib.compress(icc, 9)))
    if exif is not None:
        out.append(_chunk(b"eXIf", exif[6:] if exif.startswith(b"Exif\0\0") else exif))
    parts[0] = b"\x78\x01" + parts[0]            # zlib header: DEFLATE, 32 KiB window
    parts[-1] = parts[-1] + struct.pack(">I", adler)
    out += [_chunk(b"IDAT", p) for p in parts]
    out.append(_chunk(b"IEND", b""))
    return b"".join(out)


@dataclass(frozen=True)
class Png(StageBase):
    """Encode as PNG: orientation applied to the pixels, the sRGB ICC
    profile and EXIF embedded.

    Parameters
    ----------
    bits : {8, 16}
        Bits per sample (``--set png.bits=16`` for 16).
    level : int
        zlib level 0..9 (see :func:`encode_png`); 1 is the fastest.
    exif : bool
        Write an ``eXIf`` chunk (camera, exposure, Orientation = 1).
    threads : int
        Bands deflated at once.
    """

    name = "png"
    consumes = (Domain.DISPLAY_RGB,)
    produces = Domain.ENCODED

    bits: Literal[8, 16] = 8
    level: int = 1
    exif: bool = True
    threads: int = 2

    def __post_init__(self):
        if not 0 <= self.level <= 9:
            raise ValueError(f"level must be 0..9, got {self.level}")
        if not 1 <= self.threads <= 64:
            raise ValueError(f"threads must be 1..64, got {self.threads}")

    def process(self, frame: Frame) -> Frame:
        # to integers first: turning the image upright is then a copy of a quarter (8-bit) or
        # half (16-bit) of the float data
        img = apply_orientation(to_integer(frame.data, self.bits), frame.meta.orientation)
        data = encode_png(img, icc=srgb_icc_profile(), exif=exif_bytes(frame.meta) if self.exif else None,
                          level=self.level, threads=self.threads)
        note = f"{self.bits}-bit, sRGB profile, {len(data) / 1e6:.2f} MB"
        if frame.meta.orientation != 1:
            note += f", orientation {frame.meta.orientation} applied"
        return frame.evolve(np.frombuffer(data, dtype=np.uint8), domain=Domain.ENCODED,
                            stage=self.name, note=note)
