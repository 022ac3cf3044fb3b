"""Zemax OpticStudio sequential lens files (``.zmx``).

A ``.zmx`` file is line-oriented text: system commands at the left margin
(``UNIT``, ``FNUM``, ``ENPD``, ``FTYP``, ``YFLN``, ``WAVM``, ...) and one
``SURF n`` block per surface whose indented lines describe it (``TYPE``,
``CURV``, ``CONI``, ``PARM``, ``XDAT``, ``DISZ``, ``DIAM``, ``STOP``,
``GLAS``, ``COMM``). OpticStudio writes UTF-16 with a byte-order mark; older
versions and other programs write ASCII/UTF-8. The encoding is detected.

Surface 0 is the object (its ``DISZ`` is the object distance, ``INFINITY``
for a distant object), the last surface is the image; surfaces 1..N−1 become
the lens's surfaces with the same numbers. ``DISZ`` is the thickness after a
surface, ``GLAS`` the medium after it (none: air), ``DIAM`` its semi-diameter
(the clear aperture the tracer vignettes with).

Surface types (sag = conic base + the polynomial; coefficients in lens
units, converted to mm):

============  ================================================================
STANDARD      sphere / conic; no parameters
EVENASPH      ``PARM i`` (i = 1..8) = α_i on ρ^(2i): ρ², ρ⁴, …, ρ¹⁶. PARM 1 is
              the ρ² term, which adds 2·α₁ to the paraxial curvature.
ODDASPH       ``PARM i`` (i = 1..8) = β_i on ρ^i: ρ¹ … ρ⁸
XASPHERE      Extended Asphere: ``XDAT 1`` = number of terms N, ``XDAT 2`` =
              normalization radius R_n, ``XDAT 2+i`` (i = 1..N) = A_i on
              (ρ/R_n)^(2i), A_i in lens units. Stored as A_i/R_n^(2i) on ρ^(2i)
              (terms to ρ^40 and beyond are kept).
XOSPHERE      Extended Odd Asphere: as XASPHERE with A_i on (ρ/R_n)^i.
============  ================================================================

(OpticStudio User Guide, "Surface Types": Standard, Even Asphere, Odd
Asphere, Extended Asphere, Extended Odd Asphere; the ``XDAT`` layout — term
count, normalization radius, then the coefficients from the ρ² term — is the
Extra Data Editor's column order, as written by OpticStudio.)

Other types (coordinate breaks, toroids, gratings, user DLLs, ...) raise a
:class:`~calibration.optics.lens.LensError` naming the surface.

``GLAS ___BLANK 1 0 nd vd ...`` is a model glass (nd, vd); any other name is
looked up in :mod:`calibration.optics.materials` (in the order of the file's
``GCAT`` catalogues, then the default order). An unknown name is an error
unless ``unknown_glass="model"``, which uses the nd/vd cached on the line.

Aperture: ``FNUM`` (image-space F/#), ``ENPD`` (EPD) or ``FLOA`` (float by
stop size: the stop's ``DIAM``); ``OBNA`` (object NA) is not supported.
Field (``FTYP`` type): 0 angle (degrees), 1 object height (finite objects),
2 paraxial image height, 3 real image height; heights are converted to the
angle paraxially (a real image height with distortion converts only
approximately; the metadata says so). ``WAVM``/``WAVL`` wavelengths in µm,
``PWAV`` the primary. ``UNIT`` MM, CM, IN or METER.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from calibration.optics.io.common import (
    DEFAULT_PIXEL_PITCH_UM,
    Source,
    combined_field_angle,
    default_sensor,
    default_wavelengths,
)
from calibration.optics.lens import Lens, LensError, Surface
from calibration.optics.materials import AIR, MaterialError, lookup, model_material

SUPPORTED_TYPES = ("STANDARD", "EVENASPH", "ODDASPH", "XASPHERE", "XOSPHERE")

UNITS_MM = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "INCH": 25.4, "INCHES": 25.4, "METER": 1000.0,
            "METERS": 1000.0, "M": 1000.0}

_SURFACE_COMMANDS = {"TYPE", "CURV", "CONI", "PARM", "XDAT", "DISZ", "DIAM", "STOP", "GLAS", "COMM",
                     "MEMA", "HIDE", "MIRR", "SLAB", "POPS", "FIMP", "FLAP", "CLAP", "COAT", "SQAP",
                     "ELAP", "OBSC", "OBDC", "PZUP", "TCE", "VPAR", "PPAR", "IGNR", "BLNK"}


def decode_zmx(raw: bytes) -> str:
    """Text of a ``.zmx`` file: UTF-16 (with or without BOM), UTF-8, or
    Latin-1."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    if raw.startswith(b"\xef\xbb\xbf"):
        return raw[3:].decode("utf-8", errors="replace")
    head = raw[:400]
    if head and head.count(b"\x00") > len(head) // 4:
        # ASCII in UTF-16 without BOM: the zero bytes sit at odd (LE) or even (BE) offsets.
        odd = head[1::2].count(b"\x00")
        even = head[0::2].count(b"\x00")
        return raw.decode("utf-16-le" if odd >= even else "utf-16-be", errors="replace")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


@dataclass
class _Surf:
    number: int
    type: str = "STANDARD"
    curv: float = 0.0
    conic: float = 0.0
    parm: dict = field(default_factory=dict)
    xdat: dict = field(default_factory=dict)
    disz: float = 0.0
    diam: float = 0.0
    stop: bool = False
    glass: list | None = None
    comment: str = ""


def read_zmx(path, *, pixel_pitch_um: float | None = None, unknown_glass: str = "error") -> Lens:
    """Read a Zemax sequential ``.zmx`` file.

    Parameters
    ----------
    path : str or Path
    pixel_pitch_um : float, optional
        Pixel pitch of the assumed sensor (:func:`default_sensor`).
    unknown_glass : {"error", "model"}
        What to do with a glass name not in the catalogue: raise, or use the
        nd/vd the file caches on the ``GLAS`` line.

    Returns
    -------
    Lens

    Raises
    ------
    LensError
        One line naming the file and the surface.
    """
    src = Source(str(path))
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise src.error(f"cannot read: {e.strerror or e}") from None
    return zmx_to_lens(decode_zmx(raw), str(path), pixel_pitch_um=pixel_pitch_um,
                       unknown_glass=unknown_glass)


def zmx_to_lens(text: str, source: str = "<zmx>", *, pixel_pitch_um: float | None = None,
                unknown_glass: str = "error") -> Lens:
    """A :class:`Lens` from the text of a ``.zmx`` file (see :func:`read_zmx`)."""
    if unknown_glass not in ("error", "model"):
        raise ValueError(f"unknown_glass must be 'error' or 'model', got {unknown_glass!r}")
    src = Source(source)
    sys, surfs = _parse(src, text)
    return _build(src, sys, surfs, pixel_pitch_um, unknown_glass)


def _parse(src: Source, text: str):
    sys: dict = {"notes": [], "comments": [], "aperture": None, "gcat": [], "wavm": {}}
    surfs: list[_Surf] = []
    cur: _Surf | None = None
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("!"):
            sys["comments"].append(stripped[1:].strip())
            continue
        parts = stripped.split(None, 1)
        cmd, rest = parts[0].upper(), (parts[1] if len(parts) > 1 else "")
        if cmd == "SURF":
            n = _int(src, rest.split()[0] if rest.split() else "", "SURF number")
            if n != len(surfs):
                raise src.error(f"SURF {n} out of order (expected SURF {len(surfs)})")
            cur = _Surf(n)
            surfs.append(cur)
            continue
        indented = line[:1].isspace()
        if cur is not None and (indented or cmd in _SURFACE_COMMANDS):
            _surface_command(src, cur, cmd, rest)
        else:
            cur = None
            _system_command(src, sys, cmd, rest)
    return sys, surfs


def _tokens(rest: str) -> list[str]:
    return rest.split()


def _float(src: Source, tok: str, what: str, surface: int | None = None) -> float:
    if tok.upper() in ("INFINITY", "INF"):
        return math.inf
    try:
        v = float(tok)
    except ValueError:
        raise src.error(f"{what} must be a number, got {tok!r}", surface) from None
    if math.isnan(v):
        raise src.error(f"{what} must be a number, got {tok!r}", surface)
    return v


def _int(src: Source, tok: str, what: str, surface: int | None = None) -> int:
    v = _float(src, tok, what, surface)
    if not math.isfinite(v) or v != int(v):
        raise src.error(f"{what} must be an integer, got {tok!r}", surface)
    return int(v)


def _first(src: Source, rest: str, what: str, surface: int | None = None) -> float:
    t = _tokens(rest)
    if not t:
        raise src.error(f"{what} has no value", surface)
    return _float(src, t[0], what, surface)


def _surface_command(src: Source, s: _Surf, cmd: str, rest: str) -> None:
    n = s.number
    t = _tokens(rest)
    if cmd == "TYPE":
        s.type = t[0].upper() if t else ""
    elif cmd == "CURV":
        s.curv = _first(src, rest, "CURV", n)
    elif cmd == "CONI":
        s.conic = _first(src, rest, "CONI", n)
    elif cmd in ("PARM", "XDAT"):
        if len(t) < 2:
            raise src.error(f"{cmd} needs an index and a value, got {rest!r}", n)
        idx = _int(src, t[0], f"{cmd} index", n)
        (s.parm if cmd == "PARM" else s.xdat)[idx] = _float(src, t[1], f"{cmd} {idx}", n)
    elif cmd == "DISZ":
        s.disz = _first(src, rest, "DISZ", n)
    elif cmd == "DIAM":
        s.diam = _first(src, rest, "DIAM", n)
    elif cmd == "STOP":
        s.stop = True
    elif cmd == "GLAS":
        s.glass = t
    elif cmd == "COMM":
        s.comment = rest.strip().strip('"')


def _system_command(src: Source, sys: dict, cmd: str, rest: str) -> None:
    t = _tokens(rest)
    if cmd == "NAME":
        sys["name"] = rest.strip().strip('"')
    elif cmd == "NOTE":
        sys["notes"].append(rest.split(None, 1)[1] if len(t) > 1 and t[0].isdigit() else rest)
    elif cmd == "VERS":
        sys["version"] = rest.strip()
    elif cmd == "MODE":
        sys["mode"] = t[0].upper() if t else ""
    elif cmd == "UNIT":
        sys["unit"] = t[0].upper() if t else "MM"
    elif cmd == "FNUM":
        sys["aperture"] = ("f_number", _first(src, rest, "FNUM"))
    elif cmd == "ENPD":
        sys["aperture"] = ("epd", _first(src, rest, "ENPD"))
    elif cmd == "FLOA":
        sys["aperture"] = ("float", None)
    elif cmd in ("OBNA", "OBJA"):
        sys["aperture"] = ("unsupported", cmd)
    elif cmd == "FTYP":
        sys["ftyp"] = [_int(src, x, "FTYP entry") for x in t[:4]]
    elif cmd in ("XFLN", "YFLN", "XFLD", "YFLD"):
        sys[cmd[0]] = [_float(src, x, cmd) for x in t]
    elif cmd == "WAVM":
        if len(t) < 2:
            raise src.error(f"WAVM needs an index and a wavelength, got {rest!r}")
        sys["wavm"][_int(src, t[0], "WAVM index")] = _float(src, t[1], "WAVM wavelength")
    elif cmd == "WAVL":
        sys["wavl"] = [_float(src, x, "WAVL wavelength") for x in t]
    elif cmd == "PWAV":
        sys["pwav"] = _int(src, t[0] if t else "", "PWAV")
    elif cmd == "GCAT":
        sys["gcat"] = [x.upper() for x in t]


def _build(src: Source, sys: dict, surfs: list[_Surf], pixel_pitch_um, unknown_glass) -> Lens:
    if sys.get("mode", "SEQ") != "SEQ":
        raise src.error(f"MODE {sys['mode']} is not a sequential lens (only MODE SEQ is supported)")
    if len(surfs) < 3:
        raise src.error(f"needs an object, at least one surface and an image; found {len(surfs)} SURF blocks")
    unit = sys.get("unit", "MM")
    if unit not in UNITS_MM:
        raise src.error(f"UNIT {unit} is not supported (supported: {', '.join(sorted(UNITS_MM))})")
    scale = UNITS_MM[unit]

    obj, image = surfs[0], surfs[-1]
    if obj.glass and lookup_glass(src, obj, sys, unknown_glass) != AIR:
        raise src.error("the object space is not air (GLAS on the object surface)", 0)
    for s in (obj, image):
        if s.stop:
            raise src.error("the stop cannot be the object or the image surface", s.number)
    if image.curv != 0:
        raise src.error(f"curved image surfaces are not supported (CURV {image.curv!r})", image.number)

    surfaces = tuple(_surface(src, s, sys, scale, unknown_glass) for s in surfs[1:-1])

    kind, value = sys["aperture"] if sys["aperture"] else ("float", None)
    f_number = epd = None
    if kind == "unsupported":
        raise src.error(f"aperture type {value} (object-space NA / angle) is not supported; "
                        "use FNUM, ENPD or FLOA")
    if kind == "f_number":
        f_number = value
    elif kind == "epd":
        epd = value * scale
    elif not any(s.stop and s.semi_diameter for s in surfaces):
        raise src.error("no aperture: the file has no FNUM or ENPD, and no STOP surface with a DIAM")

    wavelengths, primary = _wavelengths(src, sys)
    object_distance = obj.disz * scale if math.isfinite(obj.disz) else math.inf
    if object_distance <= 0:
        raise src.error(f"object distance (DISZ of surface 0) must be positive, got {obj.disz!r}", 0)
    meta = {"source": {"format": "zmx", "file": Path(src.label).name, "version": sys.get("version", "")},
            "notes": sys["notes"], "comments": sys["comments"]}
    lens = src.build(surfaces=surfaces, f_number=f_number, epd=epd, wavelengths_nm=wavelengths,
                     primary_nm=primary, object_distance=object_distance,
                     name=sys.get("name", Path(src.label).stem), metadata=meta)
    lens = _apply_field(src, sys, lens, scale)
    return lens.replace(sensor=default_sensor(lens, pixel_pitch_um or DEFAULT_PIXEL_PITCH_UM))


def _surface(src: Source, s: _Surf, sys: dict, scale: float, unknown_glass: str) -> Surface:
    n = s.number
    if s.type not in SUPPORTED_TYPES:
        raise src.error(f"surface type {s.type or '(none)'!r} is not supported "
                        f"(supported: {', '.join(SUPPORTED_TYPES)})", n)
    if not math.isfinite(s.disz):
        raise src.error(f"DISZ must be finite, got {s.disz!r}", n)
    asphere = _coefficients(src, s, scale)
    mat = lookup_glass(src, s, sys, unknown_glass)
    return Surface(curvature=s.curv / scale, conic=s.conic, asphere=asphere, thickness=s.disz * scale,
                   material=mat, semi_diameter=s.diam * scale if s.diam > 0 else None, stop=s.stop,
                   name=s.comment)


def _coefficients(src: Source, s: _Surf, scale: float) -> tuple[tuple[int, float], ...]:
    """(order, coefficient in mm^(1−order)) of the surface's polynomial."""
    n = s.number
    terms: dict[int, float] = {}
    if s.type in ("EVENASPH", "ODDASPH"):
        for i, v in s.parm.items():
            if v == 0 or i == 0:
                continue
            if not 1 <= i <= 8:
                raise src.error(f"PARM {i} is not a {s.type} coefficient (PARM 1..8)", n)
            terms[2 * i if s.type == "EVENASPH" else i] = v
    elif s.type in ("XASPHERE", "XOSPHERE"):
        count = s.xdat.get(1, 0.0)
        if count != int(count) or count < 0:
            raise src.error(f"XDAT 1 (number of terms) must be a whole number, got {count!r}", n)
        rn = s.xdat.get(2, 1.0)
        if not rn > 0:
            raise src.error(f"XDAT 2 (normalization radius) must be positive, got {rn!r}", n)
        for i in range(1, int(count) + 1):
            v = s.xdat.get(2 + i, 0.0)
            if v:
                order = 2 * i if s.type == "XASPHERE" else i
                terms[order] = v / rn ** order
    return tuple((order, a * scale ** (1 - order)) for order, a in sorted(terms.items()))


def lookup_glass(src: Source, s: _Surf, sys: dict, unknown_glass: str = "error"):
    """The Material of a ``GLAS`` line (air when there is none)."""
    t = s.glass
    if not t:
        return AIR
    name = t[0]
    if name.upper() == "MIRROR":
        raise src.error("mirrors are not supported (GLAS MIRROR)", s.number)
    if name.upper().lstrip("_") == "BLANK":
        if len(t) < 5:
            raise src.error(f"model glass needs nd and vd (GLAS ___BLANK 1 0 nd vd), got {' '.join(t)!r}",
                            s.number)
        nd = _float(src, t[3], "model glass nd", s.number)
        vd = _float(src, t[4], "model glass vd", s.number)
        if not nd > 0 or not vd > 0:
            raise src.error(f"model glass needs positive nd and vd, got nd={nd!r} vd={vd!r}", s.number)
        return model_material(nd, vd)
    for cat in sys.get("gcat", []):
        try:
            return lookup(f"{cat}:{name}")
        except MaterialError:
            pass
    try:
        return lookup(name)
    except MaterialError as e:
        if unknown_glass == "model" and len(t) >= 5:
            nd, vd = _float(src, t[3], "glass nd", s.number), _float(src, t[4], "glass vd", s.number)
            if nd > 0 and vd > 0:
                return model_material(nd, vd, name=name)
        raise src.error(f"GLAS: {e}", s.number) from None


def _wavelengths(src: Source, sys: dict) -> tuple[tuple[float, ...], float]:
    count = sys["ftyp"][3] if len(sys.get("ftyp", [])) >= 4 and sys["ftyp"][3] > 0 else None
    if sys["wavm"]:
        idx = sorted(i for i in sys["wavm"] if count is None or i <= count)
        um = [sys["wavm"][i] for i in idx]
    elif "wavl" in sys:
        um = sys["wavl"][:count] if count else sys["wavl"]
        idx = list(range(1, len(um) + 1))
    else:
        return default_wavelengths()
    if not um or any(not (w > 0 and math.isfinite(w)) for w in um):
        raise src.error(f"wavelengths must be positive numbers in µm, got {um!r}")
    p = sys.get("pwav", 1)
    if p not in idx:
        raise src.error(f"PWAV {p} names no wavelength (have {len(idx)})")
    nm = tuple(w * 1e3 for w in um)
    return nm, nm[idx.index(p)]


def _apply_field(src: Source, sys: dict, lens: Lens, scale: float) -> Lens:
    ftyp = sys.get("ftyp", [0])
    kind = ftyp[0] if ftyp else 0
    count = ftyp[2] if len(ftyp) >= 3 and ftyp[2] > 0 else None
    xs, ys = sys.get("X", []), sys.get("Y", [])
    size = max(len(xs), len(ys))
    if count is not None:
        size = min(size, count)
    xs = (xs + [0.0] * size)[:size]
    ys = (ys + [0.0] * size)[:size]
    if not size:
        return lens
    from calibration.optics.paraxial import entrance_pupil, field_angle

    if kind == 0:
        theta = max(combined_field_angle(x, y) for x, y in zip(xs, ys))
    elif kind in (1, 2, 3):
        h = max(math.hypot(x, y) for x, y in zip(xs, ys)) * scale
        try:
            if kind == 1:
                if math.isinf(lens.object_distance):
                    raise src.error("field type 1 (object height) needs a finite object distance")
                z_ep, _ = entrance_pupil(lens)
                theta = math.degrees(math.atan(h / (lens.object_distance + z_ep)))
            else:
                theta = field_angle(lens, h)
        except LensError as e:
            raise src.error(str(e).removeprefix(f"{src.label}: ")) from None
        lens.metadata["field_conversion"] = (
            {1: "object height", 2: "paraxial image height", 3: "real image height"}[kind]
            + f" {h!r} mm converted to an angle paraxially at {lens.primary_nm} nm")
    else:
        raise src.error(f"field type {kind} (FTYP) is not supported (0 angle, 1 object height, "
                        "2 paraxial image height, 3 real image height)")
    return src.replace(lens, half_fov_deg=theta)

