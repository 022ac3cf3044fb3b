"""The sensor of the synthesis (restoration/synth/sensor.py).

Kind: property. The developed input is what the pipeline's WhiteBalance and
Demosaic stages hand the slot, for every CFA phase of a crop origin; the
noise variance follows the NoiseProfile it claims.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.frame import CFA, Domain, Frame

pytestmark = pytest.mark.property


def test_input_is_what_the_pipeline_hands_the_slot(cameras, rng):
    """develop() == the pipeline's WhiteBalance and Demosaic stages on the
    same mosaic, for every CFA phase of a crop origin."""
    from modules.demosaic import Demosaic
    from modules.white_balance import WhiteBalance
    from restoration.synth.sensor import develop

    meta0 = cameras[0].meta
    mos = rng.uniform(0, 1, (20, 24)).astype(np.float32)
    n = np.array([0.5, 1.0, 0.7])
    for origin in [(0, 0), (1, 0), (0, 1), (3, 5)]:
        cfa = meta0.cfa.shifted(*origin)
        meta = meta0.replace(cfa=cfa, as_shot_neutral=tuple(n), origin=(0, 0))
        fr = Demosaic()(WhiteBalance()(Frame(mos, Domain.RAW_LINEAR, meta)))
        np.testing.assert_array_equal(develop(mos, cfa, n, "malvar2004"), fr.data)


# -- noise --------------------------------------------------------------------------------

@pytest.mark.parametrize("quantise", [False, True])
def test_noise_variance_follows_the_noise_profile(quantise):
    from calibration.optics.lens import Sensor as Geo
    from isp.meta import CameraMeta
    from restoration.synth.sensor import capture_mosaic, sensor_model

    meta = CameraMeta(cfa=CFA.RGGB, white_level=(4095.0,), black_level=np.full((1, 1, 1), 256.0))
    prof = (2e-4, 4e-6)
    sensor = sensor_model(meta, Geo(1.0, 400, 400), prof)
    rng = np.random.default_rng(7)
    for level in (0.02, 0.2, 0.6):
        rgb = np.full((400, 400, 3), level)
        m = capture_mosaic(rgb, sensor, (0, 0), rng, noise=True, quantise=quantise)
        var = float(m.var())
        want = prof[0] * level + prof[1]
        # 160k samples: the variance estimate's relative s.d. is ~0.4 %
        assert var == pytest.approx(want, rel=0.03), (level, var, want)
        assert float(m.mean()) == pytest.approx(level, abs=5e-4)
