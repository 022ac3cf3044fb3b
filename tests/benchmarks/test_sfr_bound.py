"""benchmarks/sfr_bound.py: the Cramér–Rao bound on a slanted edge's blur
(kind: property). Its oracle is the estimator it bounds: a least-squares
fit of the same five unknowns to noisy renders, efficient for Gaussian
noise, must scatter as the bound says."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from benchmarks.sfr_bound import HALF_WIDTH_PX, HIGH, LOW, SIDE_PX, edge_image, mtf50_bound_pct, sigma_information

pytestmark = pytest.mark.property


def test_a_least_squares_fit_scatters_as_the_bound_says():
    angle, sigma, noise = 5.0, 1.0, 0.01
    rows, cols = int(SIDE_PX * np.cos(np.radians(angle))), 2 * HALF_WIDTH_PX + 1
    truth = np.array([sigma, HALF_WIDTH_PX + 0.3, angle, LOW, HIGH])
    clean = edge_image(rows, cols, angle, sigma, truth[1], LOW, HIGH, False)
    rng = np.random.default_rng(3)
    fitted = []
    for _ in range(60):
        img = clean + rng.normal(0.0, noise, clean.shape)
        r = least_squares(lambda p: (edge_image(rows, cols, p[2], p[0], p[1], p[3], p[4], False) - img).ravel(),
                          truth, x_scale=[0.1, 0.1, 0.1, 0.01, 0.01])
        fitted.append(r.x[0])
    bound = np.sqrt(sigma_information(angle, sigma, False)) * noise
    # 60 draws: the sample's standard deviation is within ±25 % of the truth at ~3σ
    assert 0.75 < np.std(fitted, ddof=1) / bound < 1.25
    assert abs(np.mean(fitted) - sigma) < 4 * bound / np.sqrt(60)


def test_the_bound_falls_as_the_square_root_of_the_noise_variance():
    a = mtf50_bound_pct(5.0, 1.0, True, 0.005, 16)
    b = mtf50_bound_pct(5.0, 1.0, True, 0.01, 16)
    assert b / a == pytest.approx(2.0, rel=1e-3)
    # 8 bits leave the quantisation's LSB/√12 where no noise is added
    assert mtf50_bound_pct(5.0, 1.0, True, 0.0, 8) == pytest.approx(a * (1 / (255 * np.sqrt(12))) / 0.005, rel=1e-3)
