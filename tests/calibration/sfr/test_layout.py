"""Chart layout recognition (kind: property on rendered charts; published
on the real chart files of the shared data, whose layouts are known from
their sources, and on natural photographs, which are no chart)."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.sfr.chart import _gray, measure_chart
from calibration.sfr.images import load_image
from calibration.sfr.layout import LAYOUTS, recognise_chart
from calibration.sfr.synthetic import render_square_chart
from tests.helpers import data_file, warped_square_chart


@pytest.mark.property
def test_a_rendered_grid_of_slanted_squares_is_a_square_grid_with_every_square_located():
    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.0, angles_deg=(5.0, 8.0, 11.0), side=0.5)
    lay = recognise_chart(ch.image)
    assert lay.name == "square_grid" and lay.squares == 12
    # every square's centre, to a pixel (the cells' centres of a 3 x 4 grid on 600 x 800)
    want = sorted((((c + 0.5) * 200 - 0.5, (r + 0.5) * 200 - 0.5) for r in range(3) for c in range(4)),
                  key=lambda c: (round(c[0] / 10), round(c[1] / 10)))
    got = sorted(lay.centres, key=lambda c: (round(c[0] / 10), round(c[1] / 10)))
    assert np.allclose(got, want, atol=1.0)


@pytest.mark.property
def test_one_large_slanted_square_is_a_target_and_a_uniform_image_is_nothing():
    ch = render_square_chart((400, 400), (1, 1), sigma_px=1.0, angles_deg=(6.0,), side=0.5)
    assert recognise_chart(ch.image).name == "slanted_square"
    assert recognise_chart(np.full((300, 400), 0.5)).name == "unknown"
    # an axis-aligned dark square is no slanted-edge target
    flat = np.full((400, 400), 0.8)
    flat[100:300, 100:300] = 0.2
    assert recognise_chart(flat).name == "unknown"


@pytest.mark.published
@pytest.mark.parametrize("name, layout", [
    ("sfrmat5_ISO_12233-2023_chart_digital.jpg", "esfr_2023"),     # Burns' sfrmat5: the digital e-SFR chart
    ("rayxie_webcam_iso12233_original_img.bmp", "iso12233_2000"),  # a webcam photo of the ISO 12233:2000 chart
    ("sfrmat3_ISO_DSC_300a.jpg", "slanted_square"),                # sfrmat3's "Camera SFR & OECF" target
    ("sfrmat3_ISO_DSC_300_mono.jpg", "slanted_square"),
])
def test_the_real_charts_are_recognised(name, layout):
    img, _, _ = load_image(data_file("edges", name))
    lay = recognise_chart(_gray(img, None, "srgb"))
    assert lay.name == layout, lay
    if layout == "esfr_2023":
        assert lay.pinwheels >= 5          # of the chart's nine
    assert lay.title == LAYOUTS[layout]


@pytest.mark.published
def test_natural_photographs_are_no_chart():
    """The Kodak and McMaster images (blinds, stripes, windows, a lighthouse)
    are recognised as nothing."""
    folder = data_file("latent")
    files = sorted(p for p in folder.glob("*/*") if p.suffix.lower() in (".png", ".tif", ".tiff"))
    assert len(files) >= 30
    named = {p.name: recognise_chart(_gray(load_image(p)[0], None, "srgb")).name for p in files}
    assert {k: v for k, v in named.items() if v != "unknown"} == {}


@pytest.mark.property
def test_the_layout_travels_with_the_chart_result():
    ch = render_square_chart((600, 800), (3, 4), sigma_px=1.0, angles_deg=(5.0,), side=0.5)
    d = measure_chart(ch.image).to_dict()
    assert d["layout"]["name"] == "square_grid" and d["layout"]["squares"] == 12


@pytest.mark.published
@pytest.mark.parametrize("name", ["sfrmat3_v_edge.tif", "sfrmat5_Test_edge1.tif", "sfrmat5_Test_edge1_mono.tif",
                                  "baotou_CALVAL_satellite_edge.tif"])
def test_tiff_files_read_as_opencv_reads_them(name):
    """TIFFs are read by tifffile (OpenCV stays unimported for one ROI), and
    LZW-compressed ones, which tifffile needs an optional codec for, by
    OpenCV: the pixels are OpenCV's either way (the oracle)."""
    import cv2

    path = data_file("edges", name)
    img, kind, _ = load_image(path)
    ref = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    ref = ref[..., :3][..., ::-1] if ref.ndim == 3 else ref
    assert kind == "image" and img.dtype == ref.dtype and np.array_equal(img, ref)


@pytest.mark.property
@pytest.mark.parametrize("warp", ["perspective", "barrel", "barrel_vignetting"])
def test_the_grid_is_recognised_through_perspective_distortion_and_vignetting(warp):
    """The chart of the edge search's distortion test (seen at an angle;
    barrel distortion; vignetting): still a slanted-square grid of all its
    12 squares."""
    lay = recognise_chart(warped_square_chart(warp))
    assert lay.name == "square_grid" and lay.squares == 12
