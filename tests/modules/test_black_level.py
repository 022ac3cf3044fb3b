"""The black-level stage (modules.black_level), kind: property: per-CFA
levels and deltas, negative noise kept, the linearisation table, and the
MapPolynomial opcode applied there."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, Domain, create_stage
from isp.opcodes import AreaSpec, MapPolynomial
from tests.helpers import make_frame

pytestmark = pytest.mark.property


def test_black_level_per_cfa_position_and_deltas(rng):
    # property: y = (x - B(r,c) - dV(r) - dH(c)) / (W - B(r,c)), exactly
    h, w = 6, 9  # odd width and even/odd handling
    black = np.array([[[60.0], [64.0]], [[62.0], [70.0]]])
    x = rng.uniform(100, 1000, (h, w))
    dv, dh = rng.uniform(-2, 2, h), rng.uniform(-1, 1, w)
    f = make_frame(x, cfa=CFA.RGGB, black_level=black, white_level=(1023.0,),
               black_level_delta_v=dv, black_level_delta_h=dh, active_area=(0, 0, h, w))
    out = create_stage("black_level")(f)
    b = np.tile(black[:, :, 0], (h // 2 + 1, w // 2 + 1))[:h, :w]
    expect = (x - b - dv[:, None] - dh[None, :]) / (1023.0 - b)
    assert out.domain is Domain.RAW_LINEAR
    assert np.allclose(out.data, expect, atol=2e-6)


def test_black_level_keeps_negative_noise():
    f = make_frame([[60.0, 64.0], [64.0, 1023.0]], cfa=CFA.RGGB, black_level=np.full((1, 1, 1), 64.0),
               white_level=(1023.0,))
    out = create_stage("black_level")(f).data
    assert out[0, 0] < 0 and out[1, 1] == pytest.approx(1.0)   # not clipped


def test_linearisation_table_applied_unless_the_decoder_did():
    table = np.arange(16) ** 2
    x = np.array([[3.0, 15.0]])
    f = make_frame(x, cfa=CFA.RGGB, white_level=(225.0,), linearization_table=table)
    assert np.allclose(create_stage("black_level")(f).data, [[9 / 225, 1.0]])
    done = f.meta.replace(applied_by_decoder=("LinearizationTable",))
    assert np.allclose(create_stage("black_level")(f.evolve(meta=done)).data, [[3 / 225, 15 / 225]])


def test_map_polynomial_opcode_applied_in_black_level():
    op = MapPolynomial(AreaSpec(0, 0, 2, 2, 0, 1, 1, 1), (0.0, 0.5, 0.5))  # y = x/2 + x^2/2
    f = make_frame([[0.0, 512.0], [1024.0, 256.0]], cfa=CFA.RGGB, white_level=(1024.0,), opcodes={2: (op,)})
    out = create_stage("black_level")(f)
    x = np.array([[0.0, 0.5], [1.0, 0.25]])
    assert np.allclose(out.data, x / 2 + x ** 2 / 2)
    assert "MapPolynomial" in out.history[-1].note
