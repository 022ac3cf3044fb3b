"""Images to measure: an image file as its codes, or a raw capture as its
linear Bayer mosaic (:func:`load_image`).

Imports ``isp`` (reading raw files, the black-level stage by name, errors)
and tifffile or OpenCV (lazily); nothing of the optics.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
        normalised to white = 1, with the DNG's OpcodeList1 and OpcodeList2
        applied (its GainMaps' lens-shading correction among them).
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

        # the DNG's own linearisation before demosaic: opcodes of list 1, black level, list 2 and
        # its per-phase GainMaps (lens_shading), which flatten the lens's shading: a shading slope
        # across an ROI tilts the ESF's plateaus and biases the SFR at low frequencies
        frame = Pipeline.from_names(["opcode_list1", "black_level", "opcode_list2", "lens_shading"]).run(read_raw(p))
        if frame.data.ndim != 2:
            raise InputError(path, "a linear (demosaiced) DNG; SFR of raw data needs a Bayer mosaic")
        return frame.data, "raw", frame.meta
    if p.suffix.lower() in (".tif", ".tiff"):
        return _read_tiff(p), "image", None
    img = _read_opencv(p)
    if img is None:
        raise InputError(path, "not an image OpenCV can read")
    return img, "image", None


def _read_opencv(p: Path):
    """The image OpenCV reads at ``p`` as stored (RGB order, alpha dropped), or None."""
    import cv2

    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is not None and img.ndim == 3:
        img = img[..., :3][..., ::-1]  # BGR(A) → RGB
    return img


def _read_tiff(p: Path):
    """The first image of a TIFF file (RGB order, alpha and extra samples
    dropped), by tifffile: a single-ROI run starts without OpenCV (0.08 s
    of import). A compression tifffile cannot decode without its optional
    codecs (LZW, JPEG) is read by OpenCV instead."""
    import tifffile

    try:
        img = tifffile.imread(p, key=0)
    except Exception as e:  # noqa: BLE001 — any reader failure: OpenCV's turn, then a bad file
        img = _read_opencv(p)
        if img is None:
            raise InputError(p, f"not a TIFF image tifffile or OpenCV can read ({type(e).__name__}: {e})") from None
        return img
    if img.ndim == 3 and img.shape[0] in (3, 4) and img.shape[-1] not in (3, 4):
        img = np.moveaxis(img, 0, -1)   # planar (samples first) → interleaved
    if img.ndim == 3:
        img = img[..., :3] if img.shape[-1] >= 3 else img[..., 0]
    if img.ndim != 2 and not (img.ndim == 3 and img.shape[-1] == 3):
        raise InputError(p, f"a TIFF of shape {img.shape}: expected one plane or RGB")
    return np.ascontiguousarray(img)
