"""Reading raw files into frames: pixels through rawpy (LibRaw), DNG tags
through tifffile.

``read_raw(path)`` returns a :class:`~isp.frame.Frame` in domain ``raw``:
float32 sensor values (DN) of the active area, cropped to the DNG
DefaultCrop, and a :class:`~isp.meta.CameraMeta` with every field the file
provides. It refuses, with one line naming the file and the reason, anything
it cannot turn into a Bayer mosaic or a linear DNG.

What LibRaw already did to the pixels
--------------------------------------
LibRaw applies a DNG LinearizationTable while unpacking, and for lossy
(JPEG-compressed, 8-bit) linear DNGs it evaluates the MapPolynomial opcodes
of OpcodeList2 and rescales to 16 bit. The reader records these in
``meta.applied_by_decoder`` so that no stage applies them twice. LibRaw
does not apply GainMap opcodes, BaselineExposure or ForwardMatrix (the
stages do).

Headerless sensor dumps
-----------------------
A file without any raw header is identified by LibRaw from its size alone,
often wrongly (``fastopenisp_test.RAW`` becomes a Photron camera with the
wrong CFA phase). Such files are refused unless the geometry is given as a
:class:`Headerless` (``--width --height --bits --pattern`` on the command
line).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from isp.io.dng_tags import TagReader, profile_fields, tag_dict
from isp.errors import InputError
from isp.frame import CFA, Domain, Frame
from isp.meta import LIGHT_SOURCES, CameraMeta

# Headers of raw containers LibRaw reads by structure, not by file size.
_TIFF_MAGIC = (b"II*\x00", b"MM\x00*")
_OTHER_RAW_MAGIC = (
    (0, b"FUJIFILM"), (0, b"IIRO"), (0, b"IIRS"), (0, b"MMOR"), (0, b"IIU\x00"),
    (0, b"\x00MRM"), (0, b"FOVb"), (6, b"HEAPCCDR"), (4, b"ftypcrx"), (0, b"ARRI"),
    (0, b"IIII"), (0, b"RIFF"), (0, b"\xff\xd8\xff"),
)
_KNOWN_NON_RAW = (
    (0, b"MATLAB", "a MATLAB .mat file, not a raw image"),
    (0, b"\x93NUMPY", "a numpy .npy file, not a raw image (load it with numpy)"),
    (0, b"\x89PNG", "a PNG image, not a raw image"),
    (0, b"GIF8", "a GIF image, not a raw image"),
    (0, b"%PDF", "a PDF document, not a raw image"),
    (0, b"PK\x03\x04", "a zip archive, not a raw image"),
)
_DNG_SUFFIXES = {".dng", ".tif", ".tiff"}


@dataclass(frozen=True)
class Headerless:
    """Geometry of a headerless sensor dump: little-endian unsigned samples
    (8-bit in bytes, 9–16-bit in 16-bit words), row-major, no padding.

    Parameters
    ----------
    width, height : int
        Pixels.
    bits : int
        Significant bits per sample (white level = 2**bits − 1).
    pattern : str
        CFA, e.g. ``"RGGB"``.
    black : float
        Black level in DN.
    """

    width: int
    height: int
    bits: int
    pattern: str
    black: float = 0.0

    def __post_init__(self):
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"width and height must be positive, got {self.width}x{self.height}")
        if not 1 <= self.bits <= 16:
            raise ValueError(f"bits must be 1..16, got {self.bits}")
        CFA.parse(self.pattern)


def read_raw(path: str | os.PathLike, headerless: Headerless | None = None) -> Frame:
    """Read a raw file (DNG, a camera raw LibRaw knows, or a headerless dump
    with its geometry) into a ``raw``-domain frame.

    Parameters
    ----------
    path : path-like
    headerless : Headerless, optional
        Geometry of a headerless dump; required for files without a header.

    Returns
    -------
    Frame
        ``data``: float32 DN, (H, W) Bayer mosaic or (H, W, 3) for a linear
        DNG; active area cropped to the DefaultCrop. ``meta.origin`` is the
        crop's offset inside the active area.

    Raises
    ------
    InputError
        One line naming the file and the reason.
    """
    path = Path(path)
    head = _read_head(path)
    if headerless is not None:
        return _read_headerless(path, headerless)
    _check_header(path, head)
    return _read_libraw(path)


# --------------------------------------------------------------------------
def _read_head(path: Path) -> bytes:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(path, "no such file") from None
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None
    if path.is_dir():
        raise InputError(path, "is a directory, not a file")
    if size == 0:
        raise InputError(path, "empty file (0 bytes)")
    try:
        with open(path, "rb") as f:
            return f.read(64)
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from None


def _check_header(path: Path, head: bytes) -> None:
    if head[:4] in _TIFF_MAGIC:
        return
    if any(head[o:o + len(m)] == m for o, m in _OTHER_RAW_MAGIC):
        return
    for o, m, what in _KNOWN_NON_RAW:
        if head[o:o + len(m)] == m:
            raise InputError(path, what)
    if path.suffix.lower() in _DNG_SUFFIXES:
        kind = "text" if _looks_like_text(head) else "data"
        raise InputError(path, f"not a DNG/TIFF file: no TIFF header (starts with {kind})")
    raise InputError(
        path, "no raw header: LibRaw would guess the geometry from the file size, which is "
              "unreliable; give --width, --height, --bits and --pattern to read it as a headerless dump")


def _looks_like_text(head: bytes) -> bool:
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


# --------------------------------------------------------------------------
def _read_headerless(path: Path, spec: Headerless) -> Frame:
    size = path.stat().st_size
    bytes_per = 1 if spec.bits <= 8 else 2
    need = spec.width * spec.height * bytes_per
    if size != need:
        raise InputError(path, f"headerless {spec.width}x{spec.height} at {bytes_per} byte(s)/sample "
                               f"needs {need} bytes, the file has {size}")
    data = np.fromfile(path, dtype="<u2" if bytes_per == 2 else np.uint8)
    data = data.reshape(spec.height, spec.width).astype(np.float32)
    white = float(2 ** spec.bits - 1)
    if data.max() > white:
        raise InputError(path, f"values up to {int(data.max())} exceed {spec.bits}-bit range; "
                               "check --bits")
    meta = CameraMeta(
        path=str(path), cfa=CFA.parse(spec.pattern), raw_size=data.shape,
        black_level=np.full((1, 1, 1), float(spec.black)), white_level=(white,),
        bits_per_sample=spec.bits,
        notes=("headerless dump: geometry, bits and pattern given by the user; no colour "
               "matrix, white balance or lens data",),
    )
    return Frame(data, Domain.RAW, meta)


# --------------------------------------------------------------------------
def _read_libraw(path: Path) -> Frame:
    import rawpy  # LibRaw; imported here so `isp stages` stays quick

    tags = _read_dng_tags(path)
    try:
        with rawpy.imread(str(path)) as raw:
            return _frame_from_libraw(path, raw, tags)
    except (InputError, rawpy.LibRawError) as e:
        # a compression LibRaw has no decoder for fails in odd places (at the
        # sensor layout, "unsupported format"): name the compression instead
        if tags is not None and tags.compression not in _LIBRAW_COMPRESSIONS:
            raise InputError(path, _unsupported_compression(tags.compression, rawpy.libraw_version)) from None
        if isinstance(e, InputError):
            raise
        raise _libraw_error(path, e) from None
    except MemoryError:
        raise InputError(path, "image too large to decode (out of memory)") from None


#: the raw image compressions (TIFF/DNG Compression tag) that LibRaw decodes in a DNG:
#: uncompressed, lossless JPEG, Deflate, lossy JPEG (DNG Specification 1.7.1.0, "Compression")
_LIBRAW_COMPRESSIONS = {1, 7, 8, 34892}
#: compressions a DNG-like file may use that LibRaw lacks, by name
_COMPRESSION_NAMES = {
    9: ("VC-5 (GoPro)", "convert it to a standard DNG first, e.g. with GoPro's gpr_tools "
                        "(gpr_tools -i FILE.GPR -o FILE.DNG)"),
    52546: ("JPEG XL", "re-save it without JPEG XL first, e.g. with Adobe DNG Converter"),
}


def _unsupported_compression(code: int, libraw_version) -> str:
    """The one-line reason for a raw image compressed with ``code``, which
    the installed LibRaw does not decode."""
    version = ".".join(str(v) for v in libraw_version) if isinstance(libraw_version, tuple) \
        else str(libraw_version)
    name, hint = _COMPRESSION_NAMES.get(code, ("an unknown", "convert it to a standard DNG first"))
    return f"{name} compression (Compression = {code}) is not supported by LibRaw {version}; {hint}"


def _libraw_error(path: Path, e: Exception) -> InputError:
    """The one-line error of a LibRaw exception."""
    import rawpy

    if isinstance(e, rawpy.LibRawFileUnsupportedError):
        return InputError(path, "unsupported format: not a raw file LibRaw can read")
    if isinstance(e, (rawpy.LibRawIOError, rawpy.LibRawDataError)):
        return InputError(path, f"corrupt or truncated raw data ({_libraw_msg(e)})")
    return InputError(path, f"LibRaw cannot decode it ({_libraw_msg(e)})")


def _libraw_msg(e: Exception) -> str:
    msg = e.args[0] if e.args else str(e)
    if isinstance(msg, bytes):
        msg = msg.decode("latin-1")
    return str(msg).strip() or type(e).__name__


@dataclass
class _DngTags:
    raw: dict
    ifd0: dict
    exif: dict
    compression: int
    photometric: int
    samples: int
    bits: int
    shape: tuple[int, int]


def _serial(r, tags: _DngTags) -> str:
    """DNG CameraSerialNumber (50735), else EXIF BodySerialNumber (42033); "" where neither."""
    return r.text("CameraSerialNumber") or str(_plain(tags.exif.get("BodySerialNumber", "")) or "").strip()


def camera_serial(path) -> str:
    """The serial number a DNG names (:attr:`isp.meta.CameraMeta.serial`),
    read from its tags alone; "" for another file (a TIFF, a measurement's
    JSON) or a DNG without one. A corrupt DNG raises InputError.

    >>> camera_serial("measurements.json")
    ''
    """
    p = Path(path)
    if p.suffix.lower() != ".dng" or not p.is_file():
        return ""
    tags = _read_dng_tags(p)
    return "" if tags is None else _serial(TagReader(tags.raw, tags.ifd0), tags)


def _device_calibration(r) -> str:
    """The ``device/v1`` text this project's writer stores in DNGPrivateData
    (:mod:`isp.io.device`); "" for another maker's private data or none."""
    from isp.io.device import from_private_data

    return from_private_data(r.get("DNGPrivateData"))


@contextlib.contextmanager
def _quiet(logger_name: str):
    """Silence a library's logger: tifffile logs every malformed tag it
    skips, which would bury the one-line error the user needs."""
    log = logging.getLogger(logger_name)
    level = log.level
    log.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        log.setLevel(level)


def _read_dng_tags(path: Path) -> _DngTags | None:
    """Tags of a DNG (raw IFD + IFD0 + EXIF), or None for other raws.
    Checks that the raw image's data lies inside the file (LibRaw would
    silently decode a truncated file into zeros)."""
    with _quiet("tifffile"):
        return _read_dng_tags_loud(path)


def _read_dng_tags_loud(path: Path) -> _DngTags | None:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            pages = list(tif.pages)
            if not pages:
                return None
            ifd0 = pages[0]
            t0 = tag_dict(ifd0)
            if 50706 not in t0:  # DNGVersion: not a DNG (NEF, KDC, ...)
                return None
            candidates = [ifd0] + list(ifd0.pages or [])
            raw_page = None
            for p in candidates:
                sub = p.tags.get(254)
                subtype = int(sub.value) if sub is not None else 0
                if subtype == 0 and int(p.photometric) in (32803, 34892):
                    raw_page = p
                    break
            if raw_page is None:
                raise InputError(path, "DNG without a raw image IFD (no CFA or LinearRaw "
                                       "image with NewSubfileType 0)")
            size = os.path.getsize(path)
            offsets = raw_page.dataoffsets or ()
            counts = raw_page.databytecounts or ()
            if not offsets or not counts:
                raise InputError(path, "DNG raw image has no strip/tile offsets")
            end = max(int(o) + int(c) for o, c in zip(offsets, counts))
            if end > size:
                raise InputError(path, f"truncated: the raw image needs {end} bytes, "
                                       f"the file has {size}")
            exif = {}
            if 34665 in t0 and isinstance(t0[34665][1], dict):
                exif = dict(t0[34665][1])
            bps = raw_page.bitspersample
            return _DngTags(
                raw=tag_dict(raw_page) if raw_page is not ifd0 else t0, ifd0=t0, exif=exif,
                compression=int(raw_page.compression), photometric=int(raw_page.photometric),
                samples=int(raw_page.samplesperpixel),
                bits=int(bps if np.isscalar(bps) else bps[0]),
                shape=(int(raw_page.imagelength), int(raw_page.imagewidth)),
            )
    except InputError:
        raise
    except Exception as e:  # tifffile's own errors on a mangled TIFF structure
        raise InputError(path, f"corrupt TIFF/DNG structure ({type(e).__name__}: "
                               f"{str(e)[:80]})") from None


def _frame_from_libraw(path: Path, raw, tags: _DngTags | None) -> Frame:
    import rawpy

    notes: list[str] = []
    try:
        raw_type = raw.raw_type
        colors = raw.color_desc.decode("latin-1", "replace") if raw.color_desc else ""
        sizes = raw.sizes
        pattern = raw.raw_pattern if raw_type != rawpy.RawType.Stack else None
    except (NotImplementedError, ValueError, rawpy.LibRawError) as e:
        raise InputError(path, f"LibRaw reports a sensor layout it cannot describe ({e})") from None
    if raw_type == rawpy.RawType.Stack:
        if tags is None or tags.photometric != 34892:
            raise InputError(path, f"LibRaw returns this file as {raw.raw_image.shape[-1]}-channel "
                                   "RGB, not a Bayer mosaic; only Bayer raws and linear DNGs are supported")
        mosaic = False
    else:
        if pattern is None or pattern.shape != (2, 2) or colors not in ("RGBG", "RGB"):
            shape = None if pattern is None else tuple(pattern.shape)
            raise InputError(path, f"not a Bayer sensor (CFA {shape}, colours {colors!r}); "
                                   "only 2x2 RGB Bayer patterns are supported")
        mosaic = True

    r = TagReader(tags.raw, tags.ifd0) if tags is not None else None
    raw_h, raw_w = int(sizes.raw_height), int(sizes.raw_width)

    # --- active area -----------------------------------------------------
    if r is not None and r.numbers("ActiveArea", 4) is not None:
        t, l, b, rt = (int(v) for v in r.numbers("ActiveArea", 4))
        if not (0 <= t < b <= raw_h and 0 <= l < rt <= raw_w):
            raise InputError(path, f"ActiveArea {t, l, b, rt} outside the {raw_w}x{raw_h} image")
        active = (t, l, b, rt)
    else:
        t, l = int(sizes.top_margin), int(sizes.left_margin)
        active = (t, l, t + int(sizes.height), l + int(sizes.width))

    img = raw.raw_image
    img = img[active[0]:active[2], active[1]:active[3]]
    if not mosaic:
        img = img[..., :3]

    # --- CFA --------------------------------------------------------------
    cfa = None
    if mosaic:
        cfa = _cfa_from_tags(r, notes) if r is not None else None
        if cfa is None:
            # LibRaw's raw_pattern is relative to raw_image_visible (= our
            # active area); colour index 3 is the second green
            p = np.where(pattern == 3, 1, pattern)
            try:
                cfa = CFA.from_pattern(p)
            except ValueError as e:
                raise InputError(path, str(e)) from None

    # --- default crop -----------------------------------------------------
    ah, aw = active[2] - active[0], active[3] - active[1]
    crop = None
    origin = (0, 0)
    if r is not None:
        co, cs = r.numbers("DefaultCropOrigin", 2), r.numbers("DefaultCropSize", 2)
        if co is not None and cs is not None:
            x, y = int(round(co[0])), int(round(co[1]))
            w, h = int(round(cs[0])), int(round(cs[1]))
            if x >= 0 and y >= 0 and w > 0 and h > 0 and x + w <= aw and y + h <= ah:
                crop = (x, y, w, h)
            else:
                notes.append(f"DefaultCrop origin {co} size {cs} outside the {aw}x{ah} active area; "
                             "not applied")
    if crop is not None and crop != (0, 0, aw, ah):
        x, y, w, h = crop
        img = img[y:y + h, x:x + w]
        origin = (y, x)
        if cfa is not None:
            cfa = cfa.shifted(y, x)
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise InputError(path, f"image of {img.shape[1]}x{img.shape[0]} pixels after the crop is too "
                               "small to process (needs at least one 2x2 Bayer block)")
    data = np.ascontiguousarray(img, dtype=np.float32)

    if tags is None:
        meta = _meta_from_libraw(path, raw, cfa, active, origin, notes)
    else:
        meta = _meta_from_dng(path, raw, r, tags, cfa, active, crop, origin, notes, mosaic)
    return Frame(data, Domain.RAW, meta)


def _cfa_from_tags(r: TagReader, notes: list[str]) -> CFA | None:
    dim = r.numbers("CFARepeatPatternDim", 2)
    pat = r.blob("CFAPattern")
    if dim is None or pat is None:
        return None
    if tuple(int(v) for v in dim) != (2, 2) or len(pat) != 4:
        notes.append(f"CFA repeat pattern {dim} is not 2x2")
        return None
    plane = r.blob("CFAPlaneColor") or bytes([0, 1, 2])
    try:
        colours = [plane[c] for c in pat]
    except IndexError:
        notes.append("CFAPattern refers to a colour plane that CFAPlaneColor lacks")
        return None
    try:
        return CFA.from_pattern(colours)
    except ValueError:
        return None


def _orientation_from_flip(flip: int) -> int:
    return {0: 1, 3: 3, 5: 8, 6: 6}.get(int(flip), 1)


def _meta_from_libraw(path, raw, cfa, active, origin, notes) -> CameraMeta:
    """Metadata of a non-DNG raw, from what LibRaw exposes."""
    blk = np.asarray(raw.black_level_per_channel, dtype=np.float64)
    pattern = raw.raw_pattern
    black = np.zeros((2, 2, 1))
    for i in range(2):
        for j in range(2):
            black[i, j, 0] = blk[int(pattern[i, j])]
    neutral = None
    wb = np.asarray(raw.camera_whitebalance[:3], dtype=np.float64)
    if np.all(wb > 0):
        neutral = tuple(float(v) for v in (wb[1] / wb))
    else:
        notes.append("no as-shot white balance in the file")
    cm = None
    xyz = np.asarray(raw.rgb_xyz_matrix[:3], dtype=np.float64)
    if np.any(xyz != 0):
        cm = xyz
        notes.append("ColorMatrix from LibRaw's camera table (D65)")
    else:
        notes.append("no colour matrix in the file or in LibRaw's table")
    return CameraMeta(
        path=str(path), cfa=cfa, raw_size=(int(raw.sizes.raw_height), int(raw.sizes.raw_width)),
        active_area=active, origin=origin,
        orientation=_orientation_from_flip(raw.sizes.flip),
        black_level=black, white_level=(float(raw.white_level),),
        as_shot_neutral=neutral, color_matrix_1=cm,
        calibration_illuminant_1=21 if cm is not None else None,
        notes=tuple(notes),
    )


def _meta_from_dng(path, raw, r: TagReader, tags: _DngTags, cfa, active, crop, origin,
                   notes, mosaic) -> CameraMeta:
    from isp.opcodes import OpcodeError, parse_opcode_list

    samples = 1 if mosaic else 3
    applied = []
    lossy = tags.compression == 34892

    # --- levels -------------------------------------------------------------
    dim = r.numbers("BlackLevelRepeatDim", 2) or (1.0, 1.0)
    rr, rc = max(1, int(dim[0])), max(1, int(dim[1]))
    if rr > 64 or rc > 64:
        raise InputError(path, f"BlackLevelRepeatDim {rr}x{rc} is not plausible")
    bl = r.numbers("BlackLevel")
    black = np.zeros((rr, rc, samples))
    if bl is not None:
        n = len(bl)
        if n == rr * rc * samples:
            black = np.asarray(bl, np.float64).reshape(rr, rc, samples)
        elif n == 1:
            black[:] = bl[0]
        elif n == rr * rc:
            black = np.repeat(np.asarray(bl, np.float64).reshape(rr, rc, 1), samples, axis=2)
        else:
            notes.append(f"BlackLevel has {n} values for a {rr}x{rc}x{samples} pattern; used the first")
            black[:] = bl[0]
    ah, aw = active[2] - active[0], active[3] - active[1]
    dh, dv = r.array("BlackLevelDeltaH"), r.array("BlackLevelDeltaV")
    if dh is not None and dh.size != aw:
        notes.append(f"BlackLevelDeltaH has {dh.size} values for {aw} columns; ignored")
        dh = None
    if dv is not None and dv.size != ah:
        notes.append(f"BlackLevelDeltaV has {dv.size} values for {ah} rows; ignored")
        dv = None
    wl = r.numbers("WhiteLevel")
    if wl is None:
        white = (float(2 ** min(max(tags.bits, 1), 32) - 1),) * samples
    else:
        white = tuple(float(v) for v in (wl if len(wl) == samples else [wl[0]] * samples))
    if not all(0 < v < 2 ** 32 for v in white):
        raise InputError(path, f"WhiteLevel {white} is not a usable level")
    if not np.all(np.isfinite(black)) or black.min() < 0 or black.max() >= min(white):
        raise InputError(path, f"BlackLevel {black.ravel()[:4].tolist()} does not lie below "
                               f"WhiteLevel {white[0]:g}")

    lin = r.array("LinearizationTable")
    if lin is not None:
        applied.append("LinearizationTable")

    # --- opcodes --------------------------------------------------------------
    opcodes = {}
    for k, name in ((1, "OpcodeList1"), (2, "OpcodeList2"), (3, "OpcodeList3")):
        blob = r.blob(name)
        if blob is None:
            continue
        try:
            opcodes[k] = parse_opcode_list(blob)
        except OpcodeError as e:
            raise InputError(path, f"{name}: {e}") from None

    if lossy:
        # LibRaw's lossy-DNG loader evaluates OpcodeList2 MapPolynomial on
        # planes 0-2 and rescales to 0..65535, ignoring Black/WhiteLevel
        for i, op in enumerate(opcodes.get(2, ())):
            if op.name == "MapPolynomial":
                applied.append(f"OpcodeList2[{i}] MapPolynomial")
        black = np.full((1, 1, samples), float(raw.black_level_per_channel[0]))
        white = (float(raw.white_level),) * samples
        dh = dv = None
        notes.append("lossy DNG: LibRaw decoded it to 16 bit through its MapPolynomial opcodes; "
                     f"levels taken from LibRaw (black {black.flat[0]:g}, white {white[0]:g})")

    # --- colour -----------------------------------------------------------------
    cms = [r.matrix(f"ColorMatrix{i}") for i in (1, 2, 3)]
    fms = [r.matrix(f"ForwardMatrix{i}") for i in (1, 2, 3)]
    ccs = [r.matrix(f"CameraCalibration{i}") for i in (1, 2, 3)]
    ills = [r.integer(f"CalibrationIlluminant{i}") for i in (1, 2, 3)]
    for i, code in enumerate(ills):
        if code is not None and code not in LIGHT_SOURCES:
            notes.append(f"CalibrationIlluminant{i + 1} {code} is not an EXIF light source; ignored")
            ills[i] = None
    for i in range(3):
        if cms[i] is not None and ills[i] is None:
            if i == 0 and cms[1] is None:
                notes.append("ColorMatrix1 has no CalibrationIlluminant1: used as the only "
                             "matrix, without illuminant interpolation")
            else:
                notes.append(f"ColorMatrix{i + 1} has no CalibrationIlluminant{i + 1}: "
                             "the matrices cannot be interpolated by colour temperature")
    if all(m is None for m in cms):
        notes.append("DNG without ColorMatrix: colour stays in camera space")
    neutral = r.numbers("AsShotNeutral", 3)
    if neutral is not None and not (all(0 < v <= 1e3 for v in neutral) and max(neutral) / min(neutral) < 1e3):
        notes.append(f"AsShotNeutral {neutral} is not a plausible neutral; ignored")
        neutral = None
    white_xy = r.numbers("AsShotWhiteXY", 2)
    if white_xy is not None and not (0 < white_xy[0] < 1 and 0 < white_xy[1] < 1 and sum(white_xy) < 1):
        notes.append(f"AsShotWhiteXY {white_xy} is not a chromaticity; ignored")
        white_xy = None
    if neutral is None and white_xy is None:
        notes.append("no AsShotNeutral or AsShotWhiteXY: white balance needs grey_world or manual")
    ab = r.numbers("AnalogBalance", 3)
    if ab is not None and not all(0 < v <= 1e3 for v in ab):
        notes.append(f"AnalogBalance {ab} is not usable; ignored")
        ab = None
    idata3 = r.numbers("IlluminantData3")  # noqa: F841  (DNG 1.6 xy, rarely used)

    be = r.number("BaselineExposure")  # a 0/0 or non-finite value is noted as absent
    if be is not None and abs(be) > 16:
        notes.append(f"BaselineExposure {be:g} EV is outside ±16 EV; ignored")
        be = None

    npf = r.numbers("NoiseProfile")
    noise = None
    if npf is not None:
        if len(npf) >= 2 and len(npf) % 2 == 0 and all(v >= 0 for v in npf[0::2]):
            noise = tuple((npf[i], npf[i + 1]) for i in range(0, len(npf), 2))
        else:
            notes.append(f"NoiseProfile with {len(npf)} values is malformed; ignored")

    # --- capture --------------------------------------------------------------------
    orient = r.integer("Orientation") or 1
    if not 1 <= orient <= 8:
        notes.append(f"Orientation {orient} invalid; treated as 1")
        orient = 1
    exif = {k: _plain(v) for k, v in tags.exif.items()
            if k in ("ExposureTime", "FNumber", "ISOSpeedRatings", "FocalLength",
                     "DateTimeOriginal", "LensModel", "LensMake", "FocalLengthIn35mmFilm",
                     "PhotographicSensitivity")}
    f_number = _exif_number(exif.get("FNumber")) or r.number("FNumber")
    exposure = _exif_number(exif.get("ExposureTime")) or r.number("ExposureTime")
    focal = _exif_number(exif.get("FocalLength")) or r.number("FocalLength")
    iso = exif.get("ISOSpeedRatings") or exif.get("PhotographicSensitivity") or r.integer("ISOSpeedRatings")
    if isinstance(iso, (tuple, list)):
        iso = iso[0] if iso else None
    lens = r.text("LensModel") or str(exif.get("LensModel", "") or "")
    pitch = None
    fpx = r.number("FocalPlaneXResolution")
    unit = r.integer("FocalPlaneResolutionUnit")
    if fpx and fpx > 0 and unit in (2, 3, 4):
        pitch = {2: 25400.0, 3: 10000.0, 4: 1000.0}[unit] / fpx

    if lin is not None and lin.size > 65536:
        notes.append(f"LinearizationTable has {lin.size} entries (> 65536); ignored")
        lin = None

    meta = CameraMeta(
        path=str(path), make=r.text("Make"), model=r.text("Model"),
        unique_camera_model=r.text("UniqueCameraModel"), software=r.text("Software"), serial=_serial(r, tags),
        cfa=cfa, raw_size=tags.shape, active_area=active,
        default_crop=crop, origin=origin, orientation=orient, bits_per_sample=tags.bits,
        black_level=black, black_level_delta_h=dh, black_level_delta_v=dv, white_level=white,
        linearization_table=lin, applied_by_decoder=tuple(applied),
        as_shot_neutral=neutral, as_shot_white_xy=white_xy, analog_balance=ab,
        color_matrix_1=cms[0], color_matrix_2=cms[1], color_matrix_3=cms[2],
        forward_matrix_1=fms[0], forward_matrix_2=fms[1], forward_matrix_3=fms[2],
        camera_calibration_1=ccs[0], camera_calibration_2=ccs[1], camera_calibration_3=ccs[2],
        calibration_illuminant_1=ills[0], calibration_illuminant_2=ills[1],
        calibration_illuminant_3=ills[2],
        baseline_exposure=be, noise_profile=noise, opcodes=opcodes, **profile_fields(r),
        pixel_pitch_um=pitch, focal_length_mm=focal, f_number=f_number, lens=lens,
        exposure_time_s=exposure, iso=float(iso) if iso else None,
        device_calibration=_device_calibration(r),
        datetime=str(exif.get("DateTimeOriginal", "") or "") or r.text("DateTimeOriginal"), exif=exif,
        notes=tuple(notes) + tuple(r.notes),
    )
    from isp.io.opcode_plan import opcode_plan

    skipped = tuple(f"OpcodeList{p.list_no}[{p.index}] {p.name} skipped: {p.reason}"
                    for p in opcode_plan(meta) if p.action == "skipped")
    return meta.replace(notes=meta.notes + skipped) if skipped else meta


def _plain(v):
    if isinstance(v, bytes):
        return v.decode("latin-1", "replace").strip("\x00")
    if isinstance(v, np.generic):
        return v.item()
    return v


def _exif_number(v) -> float | None:
    """An EXIF rational ((num, den) tuple) or number as float; None for 0/0."""
    if v is None:
        return None
    if isinstance(v, (tuple, list)):
        if len(v) == 2 and v[1]:
            x = v[0] / v[1]
        else:
            return None
    else:
        try:
            x = float(v)
        except (TypeError, ValueError):
            return None
    return x if math.isfinite(x) and x > 0 else None
