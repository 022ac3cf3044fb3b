"""What each command imports (kind: property): a command pays at start-up
only for the libraries its work needs. ``isp info`` imports neither
colour-science (whose package import pulls in ``colour.plotting`` and
matplotlib) nor ONNX Runtime, torch or OpenCV; ``isp process`` on a file
whose lens matches no profile imports no ONNX Runtime; forcing the
correction does (the control that shows the check sees an import). Each
command runs in a fresh interpreter, as a user starts it. No timings here:
they live in ``benchmarks/adobe_speed.py``."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from isp.frame import CFA
from isp.io.dng_write import write_dng
from isp.meta import CameraMeta

pytestmark = pytest.mark.property

#: libraries no command imports unless its work needs them
HEAVY = ("colour", "colour.plotting", "matplotlib", "onnxruntime", "torch", "cv2", "scipy")


def _loaded_by(*argv) -> tuple[int, list[str]]:
    """``isp *argv`` in a fresh interpreter: its exit code and which of
    :data:`HEAVY` it had imported when it finished."""
    code = ("import json, sys\n"
            "from isp.cli.main import main\n"
            f"code = main({[str(a) for a in argv]!r})\n"
            f"print(json.dumps([code, [m for m in {HEAVY!r} if m in sys.modules]]))\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    exit_code, loaded = json.loads(run.stdout.strip().splitlines()[-1])
    return exit_code, loaded


@pytest.fixture(scope="module")
def dng(tmp_path_factory):
    """A 64 × 96 Bayer DNG with a colour matrix and no lens identity (no
    profile matches it)."""
    meta = CameraMeta(cfa=CFA.RGGB, black_level=np.full((1, 1, 1), 64.0), white_level=(1023.0,),
                      as_shot_neutral=(0.5, 1.0, 0.6), calibration_illuminant_1=21,
                      color_matrix_1=np.array([[0.8, -0.2, -0.1], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]]),
                      make="Example", model="Startup")
    data = np.random.default_rng(0).integers(64, 1023, (64, 96)).astype(np.uint16)
    return write_dng(tmp_path_factory.mktemp("startup") / "x.dng", data, meta)


def test_info_imports_no_plotting_onnx_torch_or_opencv(dng):
    code, loaded = _loaded_by("info", dng)
    assert code == 0
    assert loaded == []


def test_process_without_a_profile_imports_no_onnxruntime(dng, tmp_path):
    code, loaded = _loaded_by("process", dng, "-o", tmp_path / "x.jpg")
    assert code == 0 and (tmp_path / "x.jpg").stat().st_size > 0
    assert not {"onnxruntime", "torch", "colour", "matplotlib"} & set(loaded), loaded


def test_forced_correction_imports_onnxruntime(dng, tmp_path):
    """The control: the check sees the import a correction model needs."""
    code, loaded = _loaded_by("process", dng, "-o", tmp_path / "x.jpg", "--correction", "default")
    assert code == 0
    assert "onnxruntime" in loaded


@pytest.fixture(scope="module")
def edge_tif(tmp_path_factory):
    """A 16-bit TIFF of one slanted edge (5°, Gaussian σ 1.2 px)."""
    import tifffile

    from calibration.sfr.synthetic import render_slanted_edge

    path = tmp_path_factory.mktemp("startup_sfr") / "edge.tif"
    img = render_slanted_edge((150, 100), 5.0, 1.2, low=0.2, high=0.8)
    tifffile.imwrite(path, np.round(img * 65535).astype(np.uint16))
    return path


def test_single_roi_sfr_imports_no_opencv_scipy_or_plotting(edge_tif):
    """``isp calib sfr ROI.tif`` reads the TIFF without OpenCV and builds
    only its own sub-command (not the fitter's, which imports the optics)."""
    code = ("import json, sys\n"
            "from isp.cli.main import main\n"
            f"c = main(['calib', 'sfr', {str(edge_tif)!r}])\n"
            f"print(json.dumps([c, [m for m in {HEAVY + ('calibration.fit.proxy', 'calibration.optics.lens')!r} "
            "if m in sys.modules]]))\n")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    exit_code, loaded = json.loads(run.stdout.strip().splitlines()[-1])
    assert exit_code == 0
    assert loaded == []


def test_chart_sfr_imports_opencv(edge_tif):
    """The control: the chart search (OpenCV's LSD) shows up as an import."""
    code, loaded = _loaded_by("calib", "sfr", edge_tif, "--chart", "--workers", "1")
    assert code == 0
    assert "cv2" in loaded
