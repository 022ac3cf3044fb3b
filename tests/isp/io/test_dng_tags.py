"""The camera profile's rendering tags (isp.io.dng_tags.profile_fields),
kind: property. Layouts the DNG specification 1.7.1.0 allows (three or two
dims, the zero-saturation column omitted), the checks Adobe's reader makes
(ProfileToneCurve pairs in [0, 1] with x increasing, encodings 0 or 1), and
a malformed tag left out with a note, never passed on; a file written with
the tags reads back into :class:`~isp.meta.CameraMeta`.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, CameraMeta
from isp.io.dng_tags import TAG, TagReader, profile_fields
from isp.io.dng_write import write_dng
from isp.io.read import read_raw

pytestmark = pytest.mark.property

FLOAT, LONG, SRATIONAL = 11, 4, 10


def _reader(**tags) -> TagReader:
    ifd0 = {TAG[name]: value for name, value in tags.items()}
    return TagReader({}, ifd0)


def test_hue_sat_maps_look_table_and_scalars():
    hsm = tuple(float(v) for v in range(4 * 3 * 1 * 3))
    lut = tuple(float(v) for v in range(6 * 2 * 2 * 3))           # sat 0 column omitted (sats 3)
    r = _reader(ProfileHueSatMapDims=(LONG, (4, 3, 1)), ProfileHueSatMapData1=(FLOAT, hsm),
                ProfileHueSatMapData2=(FLOAT, hsm), ProfileHueSatMapEncoding=(LONG, 1),
                ProfileLookTableDims=(LONG, (6, 3, 2)), ProfileLookTableData=(FLOAT, lut),
                ProfileToneCurve=(FLOAT, (0.0, 0.0, 0.5, 0.6, 1.0, 1.0)),
                BaselineExposureOffset=(SRATIONAL, (-3, 10)), DefaultBlackRender=(LONG, 1),
                ShadowScale=(5, (1, 1)))
    f = profile_fields(r)
    assert f["profile_hue_sat_map_dims"] == (4, 3, 1)
    assert f["profile_hue_sat_map_data_1"].dtype == np.float32 and f["profile_hue_sat_map_data_1"].size == 36
    assert "profile_hue_sat_map_data_3" not in f
    assert f["profile_hue_sat_map_encoding"] == 1
    assert f["profile_look_table_dims"] == (6, 3, 2) and f["profile_look_table_data"].size == 72
    np.testing.assert_array_equal(f["profile_tone_curve"], [[0, 0], [0.5, 0.6], [1, 1]])
    assert f["baseline_exposure_offset"] == pytest.approx(-0.3)
    assert f["default_black_render"] == 1 and f["shadow_scale"] == 1.0
    assert r.notes == []


def test_two_dims_mean_one_value_division():
    data = tuple(0.5 for _ in range(5 * 2 * 3))
    f = profile_fields(_reader(ProfileHueSatMapDims=(LONG, (5, 2)), ProfileHueSatMapData1=(FLOAT, data)))
    assert f["profile_hue_sat_map_dims"] == (5, 2, 1)


@pytest.mark.parametrize("tags,note", [
    ({"ProfileHueSatMapData1": (FLOAT, (1.0,) * 12)}, "ProfileHueSatMapDims missing"),
    ({"ProfileHueSatMapDims": (LONG, (2, 2, 1)), "ProfileHueSatMapData1": (FLOAT, (1.0,) * 7)},
     "ProfileHueSatMapData1 has 7 values"),
    ({"ProfileHueSatMapDims": (LONG, (2, 1, 1)), "ProfileHueSatMapData1": (FLOAT, (1.0,) * 6)},
     "not a usable table size"),
    ({"ProfileToneCurve": (FLOAT, (0.0, 0.0, 0.6, 0.5, 0.5, 0.7, 1.0, 1.0))}, "ProfileToneCurve"),
    ({"ProfileToneCurve": (FLOAT, (0.0, 0.0, 1.0))}, "ProfileToneCurve"),
    ({"ProfileLookTableEncoding": (LONG, 7)}, "ProfileLookTableEncoding 7"),
    ({"DefaultBlackRender": (LONG, 3)}, "DefaultBlackRender 3"),
    ({"BaselineExposureOffset": (SRATIONAL, (400, 10))}, "BaselineExposureOffset 40"),
])
def test_malformed_tags_are_left_out_with_a_note(tags, note):
    r = _reader(**tags)
    f = profile_fields(r)
    assert not any(k.endswith(("_data_1", "_data", "tone_curve", "black_render", "offset")) for k in f)
    assert any(note in n for n in r.notes), r.notes


def test_a_dng_with_profile_tags_reads_back(tmp_path):
    import tifffile

    meta = CameraMeta(cfa=CFA.RGGB, white_level=(1023.0,), color_matrix_1=np.eye(3),
                      calibration_illuminant_1=21, as_shot_neutral=(0.5, 1.0, 0.6))
    base = write_dng(tmp_path / "base.dng", np.full((32, 48), 300, np.uint16), meta)
    with tifffile.TiffFile(base) as tif:
        page = tif.pages[0]
        tags = [(t.code, t.dtype, t.count, t.value, True) for t in page.tags.values()
                if t.code not in (254, 256, 257, 258, 259, 262, 273, 277, 278, 279, 282, 283, 284,
                                  296, 305, 50706)]
        data = page.asarray()
    tags += [(254, "I", 1, 0, True), (50706, "B", 4, bytes([1, 6, 0, 0]), True)]
    hsm = tuple(float(v) for v in np.tile([5.0, 1.1, 0.9], 6 * 2))
    tags += [(TAG["ProfileHueSatMapDims"], "I", 3, (6, 2, 1), True),
             (TAG["ProfileHueSatMapData1"], "f", len(hsm), hsm, True),
             (TAG["ProfileToneCurve"], "f", 4, (0.0, 0.0, 1.0, 1.0), True),
             (TAG["DefaultBlackRender"], "I", 1, 1, True)]
    path = tmp_path / "profile.dng"
    with tifffile.TiffWriter(path) as tw:
        tw.write(data, photometric=32803, compression=None, extratags=sorted(tags), metadata=None)
    m = read_raw(path).meta
    assert m.profile_hue_sat_map_dims == (6, 2, 1)
    np.testing.assert_allclose(m.profile_hue_sat_map_data_1[:3], [5.0, 1.1, 0.9], rtol=1e-6)
    assert m.profile_tone_curve.shape == (2, 2) and m.default_black_render == 1
    assert m.baseline_exposure_offset is None and m.profile_look_table_data is None
