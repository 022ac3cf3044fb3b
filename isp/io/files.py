"""Writing pipeline outputs and intermediates, atomically.

Every file is written to a temporary name in the destination folder and
renamed into place, so an interrupted or failed run never leaves a partial
output (``os.replace`` is atomic on POSIX and Windows).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

from isp.errors import IspError
from isp.frame import Domain, Frame

_IMAGE_SUFFIXES = {".png", ".tif", ".tiff"}
_JPEG_SUFFIXES = {".jpg", ".jpeg"}


def default_mode() -> int:
    """Permissions a new file gets from the process umask (mkstemp's files
    are 0600, which would make outputs unreadable to others)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; on success it is renamed to
    ``path`` (with the umask's permissions), on failure removed.

    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out.bin"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_bytes(b"ok")
    >>> target.read_bytes()
    b'ok'
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as f:  # the data reach the disk before the name does
            os.fsync(f.fileno())
        os.chmod(tmp, default_mode())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file and a rename."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def encode_image(rgb: np.ndarray, suffix: str, bits: int = 16) -> bytes:
    """PNG or TIFF bytes of display RGB (float 0..1), 8 or 16 bit."""
    import cv2

    x = np.clip(np.nan_to_num(rgb, nan=0.0), 0.0, 1.0)
    if x.ndim == 3:
        x = x[..., ::-1]  # OpenCV writes BGR
    x = np.round(x * (65535 if bits == 16 else 255)).astype(np.uint16 if bits == 16 else np.uint8)
    ok, buf = cv2.imencode(suffix, np.ascontiguousarray(x))
    if not ok:
        raise IspError(f"OpenCV cannot encode {suffix}")
    return buf.tobytes()


def write_output(frame: Frame, path: str | os.PathLike) -> Path:
    """Write a pipeline's final frame.

    ``encoded`` frames (JPEG bytes) go to ``.jpg``/``.jpeg``; ``display_rgb``
    frames to 16-bit ``.png``/``.tif``. Anything else is refused: a linear
    frame needs an encoding stage first.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if frame.domain is Domain.ENCODED:
        data = bytes(frame.data)
        if data[:2] == b"\xff\xd8" and suffix not in _JPEG_SUFFIXES:
            raise IspError(f"{path}: the pipeline ends in JPEG; name the output .jpg")
        return write_bytes_atomic(path, data)
    if frame.domain is Domain.DISPLAY_RGB:
        if suffix not in _IMAGE_SUFFIXES:
            raise IspError(f"{path}: the pipeline ends in display RGB (no jpeg stage); "
                           "name the output .png or .tif")
        return write_bytes_atomic(path, encode_image(frame.data, suffix))
    raise IspError(f"{path}: the pipeline ends in {frame.domain.value}; add gamma (and jpeg) "
                   "stages to write an image")


def preview(frame: Frame) -> np.ndarray:
    """A viewable uint8 image of any frame: mosaics as grey, linear data
    through the sRGB curve (clipped), display data as is."""
    data = frame.data
    if frame.domain is Domain.RAW:
        white = float(np.max(frame.meta.white_level)) or float(data.max() or 1)
        x = data / white
    else:
        x = data
    x = np.clip(np.nan_to_num(np.asarray(x, np.float32), nan=0.0), 0.0, 1.0)
    if frame.domain is not Domain.DISPLAY_RGB:
        x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(x * 255).astype(np.uint8)


def save_stage(directory: str | os.PathLike, index: int, name: str, frame: Frame) -> list[Path]:
    """Write one intermediate as ``NN_name.npy`` (exact data) plus a viewable
    ``NN_name.png`` (or the ``.jpg`` itself for an encoded frame)."""
    d = Path(directory)
    stem = f"{index:02d}_{name}"
    out = []
    if frame.domain is Domain.ENCODED:
        out.append(write_bytes_atomic(d / f"{stem}.jpg", bytes(frame.data)))
        return out
    import io as _io

    import cv2

    buf = _io.BytesIO()
    np.save(buf, np.asarray(frame.data))
    out.append(write_bytes_atomic(d / f"{stem}.npy", buf.getvalue()))
    img = preview(frame)
    if img.ndim == 3:
        img = img[..., ::-1]
    ok, png = cv2.imencode(".png", np.ascontiguousarray(img))
    if ok:
        out.append(write_bytes_atomic(d / f"{stem}.png", png.tobytes()))
    return out
