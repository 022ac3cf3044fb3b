"""benchmarks/adobe_speed.py (kind: property): without ``dng_validate``
Adobe's half is left out while ours is still measured and published."""

import json
import numpy as np
import pytest

from benchmarks import adobe_speed
from isp.frame import CFA
from isp.io.dng_write import write_dng
from isp.meta import CameraMeta

pytestmark = pytest.mark.property


def test_without_dng_validate_ours_is_measured_and_adobes_left_out(tmp_path, monkeypatch):
    monkeypatch.setattr(adobe_speed, "find_dng_validate", lambda: None)
    meta = CameraMeta(cfa=CFA.RGGB, black_level=np.full((1, 1, 1), 64.0), white_level=(1023.0,),
                      as_shot_neutral=(0.5, 1.0, 0.6), calibration_illuminant_1=21,
                      color_matrix_1=np.array([[0.8, -0.2, -0.1], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]]))
    dng = write_dng(tmp_path / "x.dng", np.full((48, 64), 500, np.uint16), meta)
    r = adobe_speed.main(["--runs", "1", "--batch", "2", "--file", str(dng), "--info-file", str(dng),
                          "--results", str(tmp_path)])
    assert r["single"]["adobe_s"] is None and r["single"]["ratio"] is None
    assert r["single"]["ours_s"].median > 0 and r["single"]["ours_peak_mb"] > 0
    assert r["batch"]["files"] == 2 and r["batch"]["adobe_per_file_s"] is None
    assert r["met"]["single_ratio"] is None and r["met"]["batch_ratio"] is None
    assert r["megapixels"] == pytest.approx(48 * 64 / 1e6, abs=0.01)
    saved = json.loads((tmp_path / "adobe_speed.json").read_text())
    assert saved["results"]["info"]["file"] == "x.dng"
