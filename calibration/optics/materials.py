"""Optical materials: refractive index as a function of wavelength, and a
catalogue of the glasses and plastics phone and classic lenses use.

A :class:`Material` is either a catalogue glass or plastic with a published
dispersion formula, or a *model* material known only by ``nd`` (index at
the helium d line, 587.56 nm) and ``vd`` (Abbe number, (nd − 1)/(nF − nC)),
as patents give phone-lens plastics. Model materials use the two-term Cauchy
form ``n(λ) = A + B/λ²`` fitted to nd and to nF − nC = (nd − 1)/vd, which
reproduces nd exactly and the F–C dispersion exactly; a perturbation of nd or
vd (the paper's material tolerance) therefore changes the index at every
wavelength consistently.

Wavelengths in nm. Fraunhofer lines: F 486.13, d 587.56, C 656.27 nm.

Dispersion formulas (λ in µm):

=============  ============================================================
``model``      n = A + B/λ² through (nd, vd) (:func:`cauchy_from_abbe`)
``constant``   n = nd at every wavelength
``sellmeier``  n² = 1 + Σ B_i λ²/(λ² − C_i); ``coefficients`` = B1, C1,
               B2, C2, B3, C3 (C in µm²) — SCHOTT, CDGM, HOYA form
``schott``     n² = a0 + a1 λ² + a2 λ⁻² + a3 λ⁻⁴ + a4 λ⁻⁶ + a5 λ⁻⁸ (the
               Laurent series of the old SCHOTT catalogues, Zemax formula
               1); ``coefficients`` = a0, a1, a2, …
=============  ============================================================

The catalogue
-------------
Look-ups are case-insensitive and accept a catalogue prefix:
``material("N-SK16")``, ``material("schott:n-sk16")``, ``material("HIKARI
SK16")``. A bare name found in several catalogues resolves in the order of
:data:`CATALOG_PREFERENCE` (SCHOTT first). Sources:

* SCHOTT: optical glass data sheets and Zemax catalogue of 2017 (Sellmeier
  B1..C3; nd, vd as printed). N-BK7, N-K5, N-FK5, N-BAK4, N-SK2, N-SK16,
  N-SSK2, N-SSK8, N-LAK9, N-LAK22, N-BAF10, F2, F5, N-F2, SF5, N-SF5, N-SF6,
  N-SF10, N-SF11, N-SF57, N-LASF9.
* HIKARI (Nikon) glass data sheets and Nikon Zemax catalogue of 2017
  (Laurent "schott" form): SK16.
* CDGM optical glass data sheets / Zemax catalogue of 2022 (Sellmeier):
  H-K9L, D-K59 (a moldable crown used for glass-plastic hybrids).
* MISC: the Zemax MISC catalogue, after M. Bass (ed.), *Handbook of Optics*,
  Vol. II, 2nd ed., McGraw-Hill 1995 (Laurent form): PMMA, POLYCARB,
  POLYSTYR; COC from the Hoechst Celanese (Topas) data sheet.
* Phone-lens resins, as nominal nd/vd from the makers' data sheets (model
  dispersion): ZEON ZEONEX E48R, 480R, K26R; Mitsui APEL APL5014CL,
  APL5514ML; Osaka Gas Chemicals OKP4, OKP4HT; Mitsubishi Gas Chemical
  Iupizeta EP5000, EP6000, EP7000, EP8000; Teijin SP1516. The maker's sheet
  prints 3–4 decimals of nd and 1 of vd; treat these as nominal (the
  paper's material perturbation covers lot-to-lot spread).

The catalogue is read with :func:`material`; :func:`material_names` lists it.
"""

from __future__ import annotations

import difflib
import math
import re
import types
from dataclasses import dataclass, field

import numpy as np

from isp.errors import IspError

LAMBDA_F, LAMBDA_D, LAMBDA_C = 486.1327, 587.5618, 656.2725

FORMULAS = ("model", "constant", "sellmeier", "schott")


class MaterialError(IspError, ValueError):
    """An unknown material name or an ill-formed material description."""


@dataclass(frozen=True)
class Material:
    """A refractive medium.

    Attributes
    ----------
    name : str
    nd : float
        Index at 587.56 nm (for catalogue glasses: the printed value).
    vd : float
        Abbe number (inf: no dispersion).
    formula : {"model", "constant", "sellmeier", "schott"}
        How :meth:`index` is computed (see the module docstring).
    coefficients : tuple of float
        Dispersion coefficients of ``formula`` (λ in µm).
    catalog : str
        Maker's catalogue ("SCHOTT", "HIKARI", ...); "" for a model material.
    """

    name: str
    nd: float
    vd: float = math.inf
    formula: str = "model"
    coefficients: tuple[float, ...] = ()
    # Keyword-only, so that subclasses may add positional fields after ``coefficients``.
    catalog: str = field(default="", kw_only=True)

    @property
    def is_air(self) -> bool:
        return self.formula == "constant" and self.nd == 1.0

    def index(self, wavelength_nm):
        """Refractive index at ``wavelength_nm`` (scalar or array, nm).

        Returns a float for a scalar, an array of the input's shape otherwise.

        >>> round(float(Material("model", 1.544, 55.9).index(587.5618)), 6)
        1.544
        >>> round(material("N-BK7").index(587.5618), 5)
        1.5168
        """
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        if self.formula == "constant" or not math.isfinite(self.vd) and self.formula == "model":
            return np.full_like(lam, self.nd) if lam.ndim else float(self.nd)
        if self.formula == "model":
            a, b = cauchy_from_abbe(self.nd, self.vd)
            n = a + b / (lam * lam)
        elif self.formula == "sellmeier":
            um2 = (lam * 1e-3) ** 2
            c = self.coefficients
            n2 = 1.0 + sum(c[2 * i] * um2 / (um2 - c[2 * i + 1]) for i in range(len(c) // 2))
            n = np.sqrt(n2)
        elif self.formula == "schott":
            um2 = (lam * 1e-3) ** 2
            c = self.coefficients
            n2 = c[0] + (c[1] * um2 if len(c) > 1 else 0.0)
            for k, a in enumerate(c[2:], start=1):
                n2 = n2 + a * um2 ** (-k)
            n = np.sqrt(n2)
        else:
            raise MaterialError(f"material {self.name!r}: unknown formula {self.formula!r} "
                                f"(valid: {', '.join(FORMULAS)})")
        return n if lam.ndim else float(n)

    @property
    def key(self) -> str:
        """``"CATALOG:NAME"`` for a catalogue material, else the name."""
        return f"{self.catalog}:{self.name}" if self.catalog else self.name


def cauchy_from_abbe(nd: float, vd: float) -> tuple[float, float]:
    """(A, B) of n = A + B/λ² (λ in nm) with n(d) = nd and
    n(F) − n(C) = (nd − 1)/vd."""
    dn = (nd - 1.0) / vd
    b = dn / (1.0 / LAMBDA_F ** 2 - 1.0 / LAMBDA_C ** 2)
    a = nd - b / LAMBDA_D ** 2
    return a, b


def abbe_number(m: Material) -> float:
    """Abbe number (n_d − 1)/(n_F − n_C) computed from ``m``'s dispersion
    formula (dimensionless; inf for a non-dispersive medium).

    >>> round(abbe_number(material("N-SK16")), 2)
    60.32
    """
    nf, nd, nc = (m.index(w) for w in (LAMBDA_F, LAMBDA_D, LAMBDA_C))
    return math.inf if nf == nc else (nd - 1.0) / (nf - nc)


AIR = Material("air", 1.0, math.inf, "constant")


def model_material(nd: float, vd: float = math.inf, name: str = "") -> Material:
    """A model material from (nd, vd); the default name is ``"nd/vd"``
    (e.g. ``"1.544/55.9"``), so equal glasses compare equal."""
    return Material(name or default_model_name(nd, vd), float(nd), float(vd), "model")


def default_model_name(nd: float, vd: float) -> str:
    return f"{nd:g}/{vd:g}" if math.isfinite(vd) else f"{nd:g}"


# -- the catalogue ------------------------------------------------------------

def _sellmeier(catalog, name, b, c, nd, vd):
    coef = (b[0], c[0], b[1], c[1], b[2], c[2])
    return Material(name, nd, vd, "sellmeier", coef, catalog=catalog)


def _laurent(catalog, name, a, nd, vd):
    return Material(name, nd, vd, "schott", tuple(a), catalog=catalog)


def _resin(catalog, name, nd, vd):
    return Material(name, nd, vd, "model", (), catalog=catalog)


_ENTRIES = (
    # SCHOTT data sheets / Zemax catalogue of 2017: B1, B2, B3; C1, C2, C3 (µm²); nd; vd.
    _sellmeier("SCHOTT", "N-BK7", (1.03961212, 0.231792344, 1.01046945),
               (0.00600069867, 0.0200179144, 103.560653), 1.51680, 64.17),
    _sellmeier("SCHOTT", "N-K5", (1.08511833, 0.199562005, 0.930511663),
               (0.00661099503, 0.024110866, 111.982777), 1.52249, 59.48),
    _sellmeier("SCHOTT", "N-FK5", (0.844309338, 0.344147824, 0.910790213),
               (0.00475111955, 0.0149814849, 97.8600293), 1.48749, 70.41),
    _sellmeier("SCHOTT", "N-BAK4", (1.28834642, 0.132817724, 0.945395373),
               (0.00779980626, 0.0315631177, 105.965875), 1.56883, 55.98),
    _sellmeier("SCHOTT", "N-SK2", (1.28189012, 0.257738258, 0.96818604),
               (0.0072719164, 0.0242823527, 110.377773), 1.60738, 56.65),
    _sellmeier("SCHOTT", "N-SK16", (1.34317774, 0.241144399, 0.994317969),
               (0.00704687339, 0.0229005, 92.7508526), 1.62041, 60.32),
    _sellmeier("SCHOTT", "N-SSK2", (1.4306027, 0.153150554, 1.01390904),
               (0.00823982975, 0.0333736841, 106.870822), 1.62229, 53.27),
    _sellmeier("SCHOTT", "N-SSK8", (1.44857867, 0.117965926, 1.06937528),
               (0.00869310149, 0.0421566593, 111.300666), 1.61773, 49.83),
    _sellmeier("SCHOTT", "N-LAK9", (1.46231905, 0.344399589, 1.15508372),
               (0.00724270156, 0.0243353131, 85.4686868), 1.69100, 54.71),
    _sellmeier("SCHOTT", "N-LAK22", (1.14229781, 0.535138441, 1.04088385),
               (0.00585778594, 0.0198546147, 100.834017), 1.65113, 55.89),
    _sellmeier("SCHOTT", "N-BAF10", (1.5851495, 0.143559385, 1.08521269),
               (0.00926681282, 0.0424489805, 105.613573), 1.67003, 47.11),
    _sellmeier("SCHOTT", "F2", (1.34533359, 0.209073176, 0.937357162),
               (0.00997743871, 0.0470450767, 111.886764), 1.62004, 36.37),
    _sellmeier("SCHOTT", "F5", (1.3104463, 0.19603426, 0.96612977),
               (0.00958633048, 0.0457627627, 115.011883), 1.60342, 38.03),
    _sellmeier("SCHOTT", "N-F2", (1.39757037, 0.159201403, 1.2686543),
               (0.00995906143, 0.0546931752, 119.248346), 1.62005, 36.43),
    _sellmeier("SCHOTT", "SF5", (1.46141885, 0.247713019, 0.949995832),
               (0.0111826126, 0.0508594669, 112.041888), 1.67270, 32.21),
    _sellmeier("SCHOTT", "N-SF5", (1.52481889, 0.187085527, 1.42729015),
               (0.011254756, 0.0588995392, 129.141675), 1.67271, 32.25),
    _sellmeier("SCHOTT", "N-SF6", (1.77931763, 0.338149866, 2.08734474),
               (0.0133714182, 0.0617533621, 174.01759), 1.80518, 25.36),
    _sellmeier("SCHOTT", "N-SF10", (1.62153902, 0.256287842, 1.64447552),
               (0.0122241457, 0.0595736775, 147.468793), 1.72828, 28.53),
    _sellmeier("SCHOTT", "N-SF11", (1.73759695, 0.313747346, 1.89878101),
               (0.013188707, 0.0623068142, 155.23629), 1.78472, 25.68),
    _sellmeier("SCHOTT", "N-SF57", (1.87543831, 0.37375749, 2.30001797),
               (0.0141749518, 0.0640509927, 177.389795), 1.84666, 23.78),
    _sellmeier("SCHOTT", "N-LASF9", (2.00029547, 0.298926886, 1.80691843),
               (0.0121426017, 0.0538736236, 156.530829), 1.85025, 32.17),
    # HIKARI (Nikon) data sheets (2017); Laurent a0..a5.
    _laurent("HIKARI", "SK16", (2.592001, -0.01540969, 0.0102268, 0.001581559,
                                -0.0001877149, 1.012515e-05), 1.620409, 60.28),
    # CDGM data sheets / Zemax catalogue of 2022.
    _sellmeier("CDGM", "H-K9L", (0.614555251, 0.656775017, 1.02699346),
               (0.0145987884, 0.00287769588, 107.653051), 1.51680, 64.20),
    _sellmeier("CDGM", "D-K59", (1.1209538, 0.152690608, 1.07502924),
               (0.00657908073, 0.0235724778, 106.309977), 1.51760, 63.50),
    # Zemax MISC catalogue (Handbook of Optics Vol. II); Laurent a0..a5.
    _laurent("MISC", "PMMA", (2.1864582, -2.4475348e-4, 1.4155787e-2, -4.4329781e-4,
                              7.7664259e-5, -2.9936382e-6), 1.491756, 57.44),
    _laurent("MISC", "POLYCARB", (2.42838566, -3.86116645e-5, 2.87574474e-2, -1.97897366e-4,
                                  1.48358968e-4, 1.38651935e-6), 1.585470, 29.91),
    _laurent("MISC", "POLYSTYR", (2.44598368, 2.21428933e-5, 2.72988569e-2, 3.01210852e-4,
                                  8.88934888e-5, -1.75707929e-6), 1.590481, 30.87),
    _laurent("MISC", "COC", (2.28448546, 1.02952211e-2, 3.73493703e-2, -9.28409653e-3,
                             1.73289808e-3, -1.15203047e-4), 1.533732, 56.23),
    # Phone-lens resins: nominal nd / vd from the makers' data sheets.
    _resin("ZEON", "E48R", 1.531, 56.0),
    _resin("ZEON", "480R", 1.525, 56.0),
    _resin("ZEON", "K26R", 1.535, 56.0),
    _resin("MITSUI", "APL5014CL", 1.5445, 56.0),
    _resin("MITSUI", "APL5514ML", 1.544, 55.9),
    _resin("OGC", "OKP4", 1.607, 27.0),
    _resin("OGC", "OKP4HT", 1.632, 23.0),
    _resin("MGC", "EP5000", 1.635, 24.0),
    _resin("MGC", "EP6000", 1.640, 23.5),
    _resin("MGC", "EP7000", 1.650, 21.5),
    _resin("MGC", "EP8000", 1.661, 20.4),
    _resin("TEIJIN", "SP1516", 1.661, 20.3),
)

CATALOG_PREFERENCE = ("SCHOTT", "HIKARI", "CDGM", "MISC", "ZEON", "MITSUI", "OGC", "MGC", "TEIJIN")
"""Order in which a bare name found in several catalogues is resolved."""

_CATALOG_ALIASES = {
    "SCHOTT": "SCHOTT", "HIKARI": "HIKARI", "NIKON": "HIKARI", "CDGM": "CDGM", "MISC": "MISC",
    "ZEON": "ZEON", "ZEONEX": "ZEON", "MITSUI": "MITSUI", "APEL": "MITSUI", "OGC": "OGC",
    "OSAKA": "OGC", "MGC": "MGC", "IUPIZETA": "MGC", "TEIJIN": "TEIJIN",
}

_NAME_ALIASES = {
    "APEL5014": "MITSUI:APL5014CL", "APL5014": "MITSUI:APL5014CL", "APL5014DP": "MITSUI:APL5014CL",
    "APEL5514": "MITSUI:APL5514ML", "APL5514": "MITSUI:APL5514ML",
    "OKP-4": "OGC:OKP4", "OKP-4HT": "OGC:OKP4HT",
    "EP-5000": "MGC:EP5000", "EP-6000": "MGC:EP6000", "EP-7000": "MGC:EP7000", "EP-8000": "MGC:EP8000",
    "SP-1516": "TEIJIN:SP1516",
    "POLYCARBONATE": "MISC:POLYCARB", "PC": "MISC:POLYCARB",
    "POLYSTYRENE": "MISC:POLYSTYR", "PS": "MISC:POLYSTYR",
    "AIR": "air", "VACUUM": "air",
}

CATALOGUE = types.MappingProxyType({m.key.upper(): m for m in _ENTRIES})
"""Every catalogue material by ``"CATALOG:NAME"`` (upper case), read-only."""

_BY_NAME: dict[str, list[str]] = {}
for _m in _ENTRIES:
    _BY_NAME.setdefault(_m.name.upper(), []).append(_m.key.upper())
for _v in _BY_NAME.values():
    _v.sort(key=lambda k: CATALOG_PREFERENCE.index(k.split(":")[0]))

_PREFIX = re.compile(r"^\s*([A-Za-z]+)\s*[:_\s]\s*(\S.*?)\s*$")


def material_names() -> list[str]:
    """Every catalogue key (``"SCHOTT:N-BK7"``, ...), in catalogue order."""
    return [m.key for m in _ENTRIES]


def lookup(name: str) -> Material:
    """The catalogue material called ``name`` (case-insensitive; an optional
    catalogue prefix ``"SCHOTT:"``, ``"hikari "``, ``"CDGM_"``).

    Raises
    ------
    MaterialError
        Unknown name; the message lists the nearest catalogue names.

    >>> lookup("hikari sk16").key
    'HIKARI:SK16'
    >>> lookup("sk16").key     # only HIKARI carries the legacy SK16
    'HIKARI:SK16'
    """
    if not isinstance(name, str) or not name.strip():
        raise MaterialError(f"material name must be a non-empty string, got {name!r}")
    text = name.strip().upper()
    if text in _NAME_ALIASES:
        target = _NAME_ALIASES[text]
        return AIR if target == "air" else CATALOGUE[target]
    m = _PREFIX.match(text)
    if m and m.group(1) in _CATALOG_ALIASES:
        key = f"{_CATALOG_ALIASES[m.group(1)]}:{m.group(2).upper()}"
        if key in CATALOGUE:
            return CATALOGUE[key]
        raise MaterialError(f"unknown material {name!r}: {m.group(2)!r} is not in the "
                            f"{_CATALOG_ALIASES[m.group(1)]} catalogue{_suggest(m.group(2))}")
    if text in _BY_NAME:
        return CATALOGUE[_BY_NAME[text][0]]
    raise MaterialError(f"unknown material {name!r}{_suggest(text)}")


def _suggest(text: str) -> str:
    pool = sorted(set(_BY_NAME) | set(_NAME_ALIASES))
    near = difflib.get_close_matches(text.upper(), pool, n=4, cutoff=0.6)
    hint = f"; did you mean {', '.join(near)}?" if near else ""
    return (f"{hint} (catalogue: {len(CATALOGUE)} materials, see "
            f"calibration.optics.materials.material_names(); or give {{\"nd\": .., \"vd\": ..}})")


_SPEC_KEYS = ("name", "nd", "vd", "formula", "coefficients", "catalog")


def material(spec) -> Material:
    """A :class:`Material` from a catalogue name, a Material, or a dict.

    Parameters
    ----------
    spec : str, Material or dict
        A name (see :func:`lookup`); a Material (returned as is); or a dict
        with ``nd`` (and optionally ``vd``, ``name``, ``formula``,
        ``coefficients``, ``catalog``), or only ``name`` (looked up).

    Raises
    ------
    MaterialError
        Unknown name, unknown key, or a value that is not a number.

    >>> material({"nd": 1.544, "vd": 55.9}).name
    '1.544/55.9'
    >>> material("air") is AIR
    True
    """
    if isinstance(spec, Material):
        return spec
    if isinstance(spec, str):
        return lookup(spec)
    if isinstance(spec, dict):
        return _material_from_dict(spec)
    raise MaterialError(f"material must be a name or {{\"nd\": .., \"vd\": ..}}, got {spec!r}")


def _material_from_dict(spec: dict) -> Material:
    unknown = sorted(set(spec) - set(_SPEC_KEYS))
    if unknown:
        raise MaterialError(f"unknown material key {unknown[0]!r} (valid: {', '.join(_SPEC_KEYS)})")
    if "nd" not in spec:
        if "name" in spec and len(spec) == 1:
            return lookup(spec["name"])
        raise MaterialError(f"material needs 'nd' (or only a catalogue 'name'), got {spec!r}")
    nd = _number(spec["nd"], "nd")
    vd = _number(spec.get("vd", math.inf), "vd", allow_inf=True)
    if not nd > 0:
        raise MaterialError(f"material nd must be positive, got {nd!r}")
    if not vd > 0:
        raise MaterialError(f"material vd must be positive, got {vd!r}")
    formula = spec.get("formula", "model")
    if formula not in FORMULAS:
        raise MaterialError(f"material formula must be one of {', '.join(FORMULAS)}, got {formula!r}")
    coef = spec.get("coefficients", ())
    if not isinstance(coef, (list, tuple)):
        raise MaterialError(f"material coefficients must be a list of numbers, got {coef!r}")
    coef = tuple(_number(c, "coefficient") for c in coef)
    if formula == "sellmeier" and (not coef or len(coef) % 2):
        raise MaterialError(f"Sellmeier coefficients come in (B, C) pairs, got {len(coef)} numbers")
    if formula == "schott" and not coef:
        raise MaterialError("the 'schott' formula needs coefficients a0, a1, ...")
    name = spec.get("name") or (default_model_name(nd, vd) if formula == "model" else "")
    if not isinstance(name, str):
        raise MaterialError(f"material name must be a string, got {name!r}")
    catalog = spec.get("catalog", "")
    if not isinstance(catalog, str):
        raise MaterialError(f"material catalog must be a string, got {catalog!r}")
    if formula == "constant" and nd == 1.0 and not coef and name in ("", "air") and not catalog:
        return AIR
    return Material(name, nd, vd, formula, coef, catalog=catalog)


def material_to_spec(m: Material):
    """The JSON form of ``m``: ``"air"``, ``"CATALOG:NAME"`` for an unchanged
    catalogue material, else a dict that :func:`material` reads back to an
    equal Material."""
    if m == AIR:
        return "air"
    if m.catalog and CATALOGUE.get(m.key.upper()) == m:
        return m.key
    out: dict = {}
    if m.name and not (m.formula == "model" and m.name == default_model_name(m.nd, m.vd)):
        out["name"] = m.name
    out["nd"] = m.nd
    if math.isfinite(m.vd):
        out["vd"] = m.vd
    if m.formula != "model":
        out["formula"] = m.formula
    if m.coefficients:
        out["coefficients"] = list(m.coefficients)
    if m.catalog:
        out["catalog"] = m.catalog
    return out


def _number(v, what: str, allow_inf: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MaterialError(f"material {what} must be a number, got {v!r}")
    v = float(v)
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise MaterialError(f"material {what} must be finite, got {v!r}")
    return v
