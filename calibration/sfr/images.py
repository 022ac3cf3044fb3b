"""Images to measure: an image file as its codes, or a raw capture as its
linear Bayer mosaic (:func:`load_image`).

Imports ``isp`` (reading raw files, the black-level stage by name, errors)
and OpenCV (lazily); nothing of the optics.
"""

from __future__ import annotations

from pathlib import Path

from isp.errors import InputError

__all__ = ["RAW_SUFFIXES", "load_image"]


RAW_SUFFIXES = {".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw", ".kdc"}
"""File suffixes read as raw captures (LibRaw, through :func:`isp.io.read.read_raw`)."""


def load_image(path: str):
    """An image file or a raw file, as the SFR measures it.

    Parameters
    ----------
    path : str or Path
        An image OpenCV reads (PNG/TIFF/JPEG/BMP, 8 or 16 bit) or a raw file
        (a suffix of :data:`RAW_SUFFIXES`).

    Returns
    -------
    array : (H, W) or (H, W, C) ndarray
        Image codes as stored (uint8/uint16, RGB order, alpha dropped), or for
        a raw file the Bayer mosaic, float32, black level removed,
        normalised to white = 1.
    kind : {"image", "raw"}
    meta : CameraMeta or None
        A raw file's metadata (CFA, pixel pitch where known).

    Raises
    ------
    InputError
        No such file, an unreadable image, or a raw file that is not a
        Bayer mosaic.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(path, "no such file")
    if p.suffix.lower() in RAW_SUFFIXES:
        from isp import Pipeline
        from isp.io.read import read_raw

        frame = Pipeline.from_names(["black_level"]).run(read_raw(p))
        if frame.data.ndim != 2:
            raise InputError(path, "a linear (demosaiced) DNG; SFR of raw data needs a Bayer mosaic")
        return frame.data, "raw", frame.meta
    import cv2

    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "not an image OpenCV can read")
    if img.ndim == 3:
        img = img[..., :3][..., ::-1]  # BGR(A) → RGB
    return img, "image", None
