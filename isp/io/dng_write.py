"""Writing DNG files (tifffile): Bayer mosaics and linear RGB, with the
metadata :mod:`isp.io.read` reads back.

Reference: Adobe, *Digital Negative (DNG) Specification* 1.7.1.0, chapter 4.
The file is a single-IFD DNG: the raw image sits in IFD0
(NewSubfileType 0), as in many phone DNGs; TIFF/EP EXIF tags (ExposureTime,
FNumber, ISOSpeedRatings, FocalLength, DateTimeOriginal) are written into
IFD0 too, which DNG allows and LibRaw reads.

Rationals are written with a fixed denominator (10⁶ for matrices and
neutrals, 10⁴ elsewhere), so a value survives the round trip to 1e-6.
The file is written to a temporary name and renamed, so a failed write
never leaves a partial file.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

from isp.io.dng_tags import TAG
from isp.errors import IspError
from isp.frame import CFA
from isp.io.files import atomic_path
from isp.meta import CameraMeta

_DEN = 1_000_000


def _srational(values, den: int = _DEN) -> tuple[int, ...]:
    out = []
    for v in np.ravel(np.asarray(values, dtype=np.float64)):
        if not np.isfinite(v):
            raise IspError(f"cannot write non-finite value {v} as a DNG rational")
        out += [int(round(v * den)), den]
    return tuple(out)


def _rational(values, den: int = _DEN) -> tuple[int, ...]:
    vals = np.ravel(np.asarray(values, dtype=np.float64))
    if np.any(vals < 0):
        raise IspError(f"unsigned rational cannot hold negative values {vals}")
    return _srational(vals, den)


def _exif_rational(x: float) -> tuple[int, int]:
    f = Fraction(float(x)).limit_denominator(1_000_000)
    return (f.numerator, f.denominator)


def write_dng(path: str | os.PathLike, data: np.ndarray, meta: CameraMeta, *,
              software: str = "phone-isp") -> Path:
    """Write a DNG holding ``data`` and the metadata of ``meta``.

    Parameters
    ----------
    path : path-like
        Output file; written atomically (temporary file, then rename).
    data : (H, W) or (H, W, 3) uint16 ndarray
        Sensor DN: a Bayer mosaic (``meta.cfa`` gives the pattern) or linear
        RGB (``meta.cfa`` None; written as PhotometricInterpretation
        LinearRaw).
    meta : CameraMeta
        Fields written when set: make, model, unique_camera_model,
        serial (CameraSerialNumber), orientation, black_level (R, C, S
        pattern), white_level, linearization_table, active_area, default_crop, colour matrices and
        illuminants, analog_balance, as_shot_neutral / as_shot_white_xy,
        baseline_exposure, noise_profile, opcodes (lists 1–3), the EXIF
        values exposure_time_s, f_number, iso, focal_length_mm, datetime,
        lens, pixel_pitch_um (as FocalPlaneX/YResolution), and
        device_calibration (in DNGPrivateData, :mod:`isp.io.device`).
        ``meta.raw_size`` and ``meta.path`` are ignored.

    Returns
    -------
    Path of the written file.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from isp import CFA, CameraMeta
    >>> meta = CameraMeta(cfa=CFA.RGGB, white_level=(1023.0,),
    ...                   color_matrix_1=np.eye(3), calibration_illuminant_1=21,
    ...                   as_shot_neutral=(0.5, 1.0, 0.6))
    >>> mosaic = np.full((8, 12), 512, np.uint16)
    >>> out = write_dng(os.path.join(tempfile.mkdtemp(), "t.dng"), mosaic, meta)
    >>> out.stat().st_size > 0
    True
    """
    import tifffile

    from isp.opcodes import serialize_opcode_list

    path = Path(path)
    data = np.asarray(data)
    if data.dtype != np.uint16:
        raise IspError(f"DNG data must be uint16 DN, got {data.dtype}")
    linear = data.ndim == 3
    if linear and data.shape[2] != 3:
        raise IspError(f"linear DNG data must be (H, W, 3), got {data.shape}")
    if not linear and data.ndim != 2:
        raise IspError(f"mosaic data must be (H, W), got {data.shape}")
    if not linear and meta.cfa is None:
        raise IspError("a mosaic needs meta.cfa")
    samples = 3 if linear else 1

    tags: list[tuple] = []

    def add(name, dtype, count, value):
        tags.append((TAG[name], dtype, count, value, True))

    add("DNGVersion", "B", 4, bytes([1, 4, 0, 0]))
    tags.append((50707, "B", 4, bytes([1, 3, 0, 0]), True))  # DNGBackwardVersion
    add("UniqueCameraModel", "s", 0, meta.unique_camera_model or meta.model or "phone-isp camera")
    if meta.make:
        add("Make", "s", 0, meta.make)
    if meta.model:
        add("Model", "s", 0, meta.model)
    if meta.serial:
        add("CameraSerialNumber", "s", 0, meta.serial)
    add("Orientation", "H", 1, int(meta.orientation))
    if not linear:
        add("CFARepeatPatternDim", "H", 2, (2, 2))
        add("CFAPattern", "B", 4, bytes(int(v) for v in CFA.parse(meta.cfa).pattern.ravel()))
        tags.append((TAG["CFAPlaneColor"], "B", 3, bytes([0, 1, 2]), True))
        tags.append((TAG["CFALayout"], "H", 1, 1, True))

    bl = np.asarray(meta.black_level, dtype=np.float64)
    if bl.ndim != 3:
        bl = bl.reshape(1, 1, -1)
    if bl.shape[2] not in (1, samples):
        raise IspError(f"black_level pattern {bl.shape} does not fit {samples} sample(s)")
    if bl.shape[2] != samples:
        bl = np.repeat(bl, samples, axis=2)
    add("BlackLevelRepeatDim", "H", 2, (bl.shape[0], bl.shape[1]))
    add("BlackLevel", "2I", bl.size, _rational(bl.ravel(), 10_000))
    if meta.black_level_delta_h is not None:
        add("BlackLevelDeltaH", "2i", len(meta.black_level_delta_h), _srational(meta.black_level_delta_h, 10_000))
    if meta.black_level_delta_v is not None:
        add("BlackLevelDeltaV", "2i", len(meta.black_level_delta_v), _srational(meta.black_level_delta_v, 10_000))
    wl = [int(round(v)) for v in meta.white_level]
    wl = wl if len(wl) == samples else [wl[0]] * samples
    add("WhiteLevel", "I", samples, tuple(wl) if samples > 1 else wl[0])
    if meta.linearization_table is not None:
        lt = np.asarray(meta.linearization_table)
        add("LinearizationTable", "H", lt.size, tuple(int(v) for v in lt.ravel()))

    h, w = data.shape[:2]
    if meta.active_area is not None:
        t, l, b, r = meta.active_area
        if not (0 <= t < b <= h and 0 <= l < r <= w):
            raise IspError(f"active_area {meta.active_area} outside the {w}x{h} image")
        add("ActiveArea", "I", 4, tuple(int(v) for v in meta.active_area))
    if meta.default_crop is not None:
        x, y, cw, ch = meta.default_crop
        add("DefaultCropOrigin", "I", 2, (int(x), int(y)))
        add("DefaultCropSize", "I", 2, (int(cw), int(ch)))

    for i in (1, 2, 3):
        for kind in ("ColorMatrix", "ForwardMatrix", "CameraCalibration"):
            attr = {"ColorMatrix": "color_matrix", "ForwardMatrix": "forward_matrix",
                    "CameraCalibration": "camera_calibration"}[kind]
            m = getattr(meta, f"{attr}_{i}")
            if m is not None:
                add(f"{kind}{i}", "2i", 9, _srational(m))
        ill = getattr(meta, f"calibration_illuminant_{i}")
        if ill is not None:
            add(f"CalibrationIlluminant{i}", "H", 1, int(ill))
    if meta.analog_balance is not None:
        add("AnalogBalance", "2I", 3, _rational(meta.analog_balance))
    if meta.as_shot_neutral is not None:
        add("AsShotNeutral", "2I", 3, _rational(meta.as_shot_neutral))
    elif meta.as_shot_white_xy is not None:
        add("AsShotWhiteXY", "2I", 2, _rational(meta.as_shot_white_xy))
    if meta.baseline_exposure is not None:
        add("BaselineExposure", "2i", 1, _srational([meta.baseline_exposure]))
    if meta.noise_profile is not None:
        flat = [float(v) for pair in meta.noise_profile for v in pair]
        add("NoiseProfile", "d", len(flat), tuple(flat))
    for k, name in ((1, "OpcodeList1"), (2, "OpcodeList2"), (3, "OpcodeList3")):
        ops = meta.opcodes.get(k)
        if ops:
            blob = serialize_opcode_list(ops)
            add(name, "B", len(blob), blob)

    if meta.exposure_time_s:
        add("ExposureTime", "2I", 1, _exif_rational(meta.exposure_time_s))
    if meta.f_number:
        add("FNumber", "2I", 1, _exif_rational(meta.f_number))
    if meta.iso:
        add("ISOSpeedRatings", "H", 1, int(round(meta.iso)))
    if meta.focal_length_mm:
        add("FocalLength", "2I", 1, _exif_rational(meta.focal_length_mm))
    if meta.datetime:
        add("DateTimeOriginal", "s", 0, meta.datetime)
    if meta.lens:
        add("LensModel", "s", 0, meta.lens)
    if meta.pixel_pitch_um:
        # TIFF/EP focal-plane resolution in pixels per cm (unit 3)
        ppcm = _exif_rational(1e4 / meta.pixel_pitch_um)
        add("FocalPlaneXResolution", "2I", 1, ppcm)
        add("FocalPlaneYResolution", "2I", 1, ppcm)
        add("FocalPlaneResolutionUnit", "H", 1, 3)

    if meta.device_calibration:
        from isp.io.device import private_data

        blob = private_data(meta.device_calibration)
        add("DNGPrivateData", "B", len(blob), blob)

    tags.sort(key=lambda t: t[0])
    with atomic_path(path) as tmp, tifffile.TiffWriter(tmp) as tw:
        tw.write(data, photometric=34892 if linear else 32803, compression=None,
                 planarconfig="contig" if linear else None, extratags=tags,
                 subfiletype=0, software=software, metadata=None)
    return path
