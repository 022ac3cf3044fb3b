"""The white-balance stage (modules.white_balance), kind: property: as-shot,
grey-world and manual gains, the as-shot white given as xy, and the refusal
of manual mode without gains."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, Domain, create_stage
from tests.helpers import make_frame

pytestmark = pytest.mark.property


def test_white_balance_modes(rng):
    cast = np.array([0.5, 1.0, 0.7])
    grey = rng.uniform(0.1, 0.8, (64, 64, 1)) * cast      # a grey world seen through a cast
    f = make_frame(grey, Domain.RAW_LINEAR, as_shot_neutral=tuple(cast))
    for mode in ("as_shot", "grey_world"):
        out = create_stage("white_balance", mode=mode)(f)
        assert np.allclose(out.neutral, cast, rtol=1e-3)
        assert np.allclose(out.data[..., 0], out.data[..., 1], rtol=1e-3)
    man = create_stage("white_balance", mode="manual", gains=(2.0, 1.0, 1.0 / 0.7))(f)
    assert np.allclose(man.data[..., 0], man.data[..., 1], rtol=1e-6)
    # no as-shot white in the file: grey world, and the history says so
    bare = create_stage("white_balance")(make_frame(grey, Domain.RAW_LINEAR))
    assert "grey world (no as-shot white" in bare.history[-1].note


def test_white_balance_from_as_shot_white_xy():
    m = np.array([[0.7, -0.1, -0.05], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]])
    f = make_frame(np.ones((4, 4)), Domain.RAW_LINEAR, cfa=CFA.RGGB, color_matrix_1=m,
               calibration_illuminant_1=21, as_shot_white_xy=(0.3127, 0.3290))
    out = create_stage("white_balance")(f)
    from modules.ccm import xy_to_camera_neutral

    n = xy_to_camera_neutral(f.meta, (0.3127, 0.3290))
    assert np.allclose(out.neutral, n / n[1])


def test_manual_white_balance_needs_gains():
    from isp import ConfigError
    with pytest.raises(ConfigError, match="needs gains"):
        create_stage("white_balance", mode="manual")
