"""Materials: the catalogue's dispersion formulas against the makers'
published nd / vd (kind: published), and look-up behaviour (kind: property).

Published values, as printed on the data sheets (nd to 5 decimals, vd to 2):
SCHOTT optical glass data sheets (2017); HIKARI (Nikon) glass data
sheets (2017); CDGM optical glass data sheets (2022); the Zemax MISC
catalogue after M. Bass (ed.), Handbook of Optics Vol. II (1995) for the
plastics (nd to 6 decimals); the table is ``tests/data/reference/glass_nd_vd.csv``.
The check is the formula of the catalogue entry evaluated at the F, d, C
lines, so a mistyped coefficient shows up.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.optics.materials import (
    AIR, CATALOGUE, LAMBDA_C, LAMBDA_D, LAMBDA_F, Material, MaterialError, abbe_number,
    lookup, material, material_names, material_to_spec, model_material,
)
from tests.helpers import reference

# key: (nd, vd) as printed by the maker
PUBLISHED = {row["material"]: (row["nd"], row["vd"]) for row in reference("glass_nd_vd.csv")}


@pytest.mark.published
@pytest.mark.parametrize("key", sorted(PUBLISHED))
def test_formula_reproduces_published_nd_vd(key):
    """published: the dispersion formula gives the printed nd to 1e-5 and vd to 0.1."""
    m = CATALOGUE[key.upper()]
    assert m.formula in ("sellmeier", "schott")
    nd, vd = PUBLISHED[key]
    assert abs(m.index(LAMBDA_D) - nd) < 1e-5
    assert abs(abbe_number(m) - vd) < 0.1


@pytest.mark.property
def test_every_formula_glass_has_a_published_check():
    """property: a catalogue entry with a formula is in the published table."""
    with_formula = {k for k, m in CATALOGUE.items() if m.formula in ("sellmeier", "schott")}
    assert with_formula == {k.upper() for k in PUBLISHED}


@pytest.mark.property
@pytest.mark.parametrize("key", sorted(CATALOGUE))
def test_catalogue_nd_vd_fields_match_formula(key):
    """property: an entry's nd/vd fields agree with its own index()."""
    m = CATALOGUE[key]
    assert abs(m.index(LAMBDA_D) - m.nd) < 1e-5
    assert abs(abbe_number(m) - m.vd) < 0.1


@pytest.mark.property
@pytest.mark.parametrize("spec, key", [
    ("N-SK16", "SCHOTT:N-SK16"), ("n-sk16", "SCHOTT:N-SK16"), ("SCHOTT:N-SK16", "SCHOTT:N-SK16"),
    ("schott n-sk16", "SCHOTT:N-SK16"), ("hikari SK16", "HIKARI:SK16"), ("HIKARI:sk16", "HIKARI:SK16"),
    ("sk16", "HIKARI:SK16"), ("f2", "SCHOTT:F2"), ("CDGM_H-K9L", "CDGM:H-K9L"), ("E48R", "ZEON:E48R"),
    ("zeonex e48r", "ZEON:E48R"), ("APEL5014", "MITSUI:APL5014CL"), ("okp-4ht", "OGC:OKP4HT"),
    ("polycarbonate", "MISC:POLYCARB"), ("EP-8000", "MGC:EP8000"),
])
def test_lookup_is_case_insensitive_with_prefixes(spec, key):
    """property"""
    assert lookup(spec).key == key


@pytest.mark.property
def test_unknown_name_lists_near_matches():
    """property: the error names the input and suggests catalogue names."""
    with pytest.raises(MaterialError) as e:
        material("N-SK61")
    msg = str(e.value)
    assert "'N-SK61'" in msg and "N-SK16" in msg and "\n" not in msg
    with pytest.raises(MaterialError, match="not in the SCHOTT catalogue"):
        material("SCHOTT:SK16")


@pytest.mark.property
def test_material_accepts_material_dict_and_air():
    """property"""
    m = model_material(1.544, 55.9)
    assert material(m) is m
    assert material({"nd": 1.544, "vd": 55.9}) == m
    assert material("air") is AIR and material({"nd": 1.0, "formula": "constant"}) == AIR
    with pytest.raises(MaterialError, match="unknown material key 'n'"):
        material({"n": 1.5})
    with pytest.raises(MaterialError, match="nd must be a number, got 'x'"):
        material({"nd": "x"})
    with pytest.raises(MaterialError):
        material(3)


@pytest.mark.property
@pytest.mark.parametrize("m", [model_material(1.544, 55.9), model_material(1.5), CATALOGUE["SCHOTT:N-BK7"],
                               Material("custom", 1.6, 40.0, "sellmeier", (1.0, 0.01, 0.2, 0.05), catalog="X"),
                               Material("n=1.7", 1.7, math.inf, "constant"), AIR])
def test_spec_round_trip(m):
    """property: material(material_to_spec(m)) == m."""
    assert material(material_to_spec(m)) == m


@pytest.mark.property
def test_index_is_vectorised_and_model_exact():
    """property: arrays in, arrays out; the model glass reproduces nd and nF − nC."""
    m = model_material(1.639, 23.5)
    lam = np.array([[LAMBDA_F, LAMBDA_D], [LAMBDA_C, 550.0]])
    n = m.index(lam)
    assert n.shape == lam.shape
    assert n[0, 1] == pytest.approx(1.639, abs=1e-14)
    assert (n[0, 0] - n[1, 0]) == pytest.approx(0.639 / 23.5, rel=1e-12)
    for key in ("SCHOTT:N-BK7", "HIKARI:SK16"):
        g = CATALOGUE[key]
        assert np.allclose(g.index(lam), [[g.index(float(x)) for x in row] for row in lam])
    assert isinstance(CATALOGUE["SCHOTT:N-BK7"].index(550.0), float)


@pytest.mark.property
def test_material_names_lists_the_catalogue():
    """property"""
    names = material_names()
    assert len(names) == len(CATALOGUE) and "SCHOTT:N-BK7" in names
