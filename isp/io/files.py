"""Writing pipeline outputs and intermediates, atomically, and which
encoding stage an output's extension asks for.

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

from isp.errors import ConfigError, IspError
from isp.frame import Domain, Frame

#: the encoding stage (``modules``) that writes each output extension
ENCODERS: dict[str, str] = {".jpg": "jpeg", ".jpeg": "jpeg", ".png": "png", ".tif": "tiff", ".tiff": "tiff"}
#: the formats :data:`ENCODERS` covers, as error messages list them
FORMATS = ".jpg/.jpeg (JPEG), .png (PNG), .tif/.tiff (TIFF)"
_SIGNATURES = (("jpeg", b"\xff\xd8"), ("png", b"\x89PNG\r\n\x1a\n"), ("tiff", b"II*\x00"),
               ("tiff", b"MM\x00*"))


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


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_bytes_atomic(path: str | os.PathLike, data) -> Path:
    """Write ``data`` (bytes or any contiguous buffer, e.g. a uint8 array) to
    ``path`` via a temporary file and a rename."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def encoder_for(path: str | os.PathLike) -> str:
    """The encoding stage that writes ``path``, chosen by its extension
    (:data:`ENCODERS`, case-insensitive).

    Raises
    ------
    ConfigError
        An extension no encoding stage writes; the message names the file
        and the formats.

    >>> encoder_for("photo.TIF")
    'tiff'
    """
    suffix = Path(path).suffix.lower()
    if suffix not in ENCODERS:
        what = f"extension {suffix!r}" if suffix else "no extension"
        raise ConfigError(f"{path}: unknown output format ({what}); formats: {FORMATS}")
    return ENCODERS[suffix]


def encoded_format(data: bytes) -> str | None:
    """The encoding stage whose format ``data`` has, by its signature
    (JPEG SOI, the PNG signature, a TIFF header), or None.

    >>> encoded_format(b"\\x89PNG\\r\\n\\x1a\\n...")
    'png'
    """
    for name, magic in _SIGNATURES:
        if data.startswith(magic):
            return name
    return None


def write_output(frame: Frame, path: str | os.PathLike) -> Path:
    """Write a pipeline's final frame to ``path``, atomically.

    ``encoded`` frames (a file's bytes) are written as they are, to a name
    whose extension is their format's (:data:`ENCODERS`). A ``display_rgb``
    frame is first encoded by the stage of the extension with its default
    parameters (:func:`encoder_for`). Anything else is refused: a linear
    frame needs an encoding stage first.

    Raises
    ------
    ConfigError
        The extension does not match the encoded format, or is unknown.
    IspError
        A frame in a domain no encoder takes here.
    """
    path = Path(path)
    encoder = encoder_for(path)
    if frame.domain is Domain.DISPLAY_RGB:
        from isp.registry import create_stage

        frame = create_stage(encoder)(frame)
    if frame.domain is Domain.ENCODED:
        data = np.ascontiguousarray(frame.data, dtype=np.uint8)   # written as it is, not copied
        made = encoded_format(data[:16].tobytes())
        if made is not None and made != encoder:
            names = "/".join(s for s, e in ENCODERS.items() if e == made)
            raise ConfigError(f"{path}: the pipeline ends in the {made} stage; name the output {names} "
                              "(or end the pipeline in the encoder of the extension)")
        return write_bytes_atomic(path, data)
    raise IspError(f"{path}: the pipeline ends in {frame.domain.value}; add gamma (and an encoding "
                   "stage) to write an image")


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
    ``NN_name.png`` (or the encoded file itself for an encoded frame:
    ``.jpg``, ``.png`` or ``.tif``)."""
    d = Path(directory)
    stem = f"{index:02d}_{name}"
    out = []
    if frame.domain is Domain.ENCODED:
        data = bytes(frame.data)
        suffix = {"jpeg": ".jpg", "png": ".png", "tiff": ".tif"}.get(encoded_format(data) or "", ".bin")
        out.append(write_bytes_atomic(d / f"{stem}{suffix}", data))
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
