"""The analytic chart oracle (kind: property): a square's side renders as
the exact slanted edge away from its corners, point-sampled charts are the
Gaussian CDF at pixel centres, and each side carries its true MTF50."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from calibration.sfr.synthetic import mtf50_of, render_slanted_edge, render_square_chart

pytestmark = pytest.mark.property


def _right_side(chart):
    """The vertical side right of the square's centre, and a crop around its middle."""
    e = max((e for e in chart.edges if e.orientation == "vertical"), key=lambda e: e.centre[0])
    x0, y0 = int(e.centre[0]) - 20, int(e.centre[1]) - 40
    return e, x0, y0, chart.image[y0:y0 + 80, x0:x0 + 40]


@pytest.mark.parametrize("sigma", [0.6, 1.5])
def test_a_side_away_from_its_corners_is_the_exact_slanted_edge(sigma):
    ch = render_square_chart((600, 600), (1, 1), sigma_px=sigma, angles_deg=(5.0,), side=0.6)
    e, x0, y0, crop = _right_side(ch)
    ref = render_slanted_edge((80, 40), -5.0, sigma, low=0.2, high=0.8, center=(e.centre[0] - x0, e.centre[1] - y0))
    assert np.abs(crop - ref).max() < 1e-9


def test_point_sampling_is_the_gaussian_cdf_at_pixel_centres():
    ch = render_square_chart((600, 600), (1, 1), sigma_px=1.2, angles_deg=(7.0,), side=0.6, pixel_aperture=False)
    e, x0, y0, crop = _right_side(ch)
    th = np.deg2rad(7.0)
    yy, xx = np.mgrid[y0:y0 + 80, x0:x0 + 40].astype(float)
    d = (xx - e.centre[0]) * np.cos(th) + (yy - e.centre[1]) * np.sin(th)   # outward normal of the right side
    assert np.abs(crop - (0.2 + 0.6 * ndtr(d / 1.2))).max() < 1e-12


def test_every_side_carries_its_truth():
    ch = render_square_chart((300, 400), (2, 3), sigma_px=1.0, angles_deg=(5.0, 33.0), side=0.5)
    assert len(ch.edges) == 24
    for e in ch.edges:
        a = 5.0 if e.square % 2 == 0 else 33.0
        assert e.angle_deg == pytest.approx(a)
        assert e.mtf50 == pytest.approx(mtf50_of(1.0, a))
    # a square's four sides: two near-vertical, two near-horizontal, a side apart across its centre
    four = [e for e in ch.edges if e.square == 0]
    assert sorted(e.orientation for e in four) == ["horizontal", "horizontal", "vertical", "vertical"]
    assert float(ch.image.min()) >= 0.2 - 1e-12 and float(ch.image.max()) <= 0.8 + 1e-12


def test_bad_input():
    with pytest.raises(ValueError, match="sigma_px"):
        render_square_chart((100, 100), sigma_px=0.0)
    with pytest.raises(ValueError, match="too small"):
        render_square_chart((100, 100), (5, 5), sigma_px=2.0)
