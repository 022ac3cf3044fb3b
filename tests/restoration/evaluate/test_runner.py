"""The correction models the evaluation runs (restoration/evaluate/runner.py).

Kind: property. An ONNX model runs through the correction stage (tiles,
field channels) and a channel-selecting one scores as the uncorrected
pipeline, at the slot and at the placement ablation's other places; a model
for another domain is refused; a checkpoint and its ONNX export score
alike (torch ↔ ONNX); a checkpoint whose reach exceeds the tile runs on
larger tiles. PSF maps are small synthetic ones (no optics computed).
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import onnx_select_rgb
from tests.helpers import ring_psf_map as psf_map

pytestmark = pytest.mark.property


QUIET = create_executor("serial")          # the crops in this process, no progress bar


def test_onnx_identity_through_the_correction_stage(make, tmp_path):
    """An ONNX model run by the correction stage (tiles, field channels):
    a channel-selecting model scores exactly as the uncorrected pipeline."""
    from restoration.evaluate.rings import evaluate_plan
    from restoration.evaluate.runner import OnnxRunner, load_runner

    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx"))
    assert isinstance(runner, OnnxRunner) and runner.meta["fov_encoding"] == "xy"
    plan, es = make([psf_map()], baseline="none")
    res = evaluate_plan(plan, runner, es, executor=QUIET)
    for ring in res["rings"].values():
        assert ring["psnr_corrected"] == pytest.approx(ring["psnr_uncorrected"], abs=1e-6)


@pytest.mark.parametrize("domain", ["display_rgb", "linear_rgb"])
def test_identity_at_the_other_placements_scores_as_uncorrected(make, tmp_path, domain):
    """The placement ablation's models run where they were trained: at the
    end of the pipeline (fed the processed input, scored as they return it)
    or between the colour matrix and the gamma (fed linear sRGB, their
    output encoded by the gamma): an identity model scores as the
    uncorrected pipeline at either."""
    from restoration.evaluate.rings import evaluate_plan
    from restoration.evaluate.runner import load_runner

    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx", {"domain": domain}))
    plan, es = make([psf_map()], baseline="none")
    res = evaluate_plan(plan, runner, es, executor=QUIET)
    for ring in res["rings"].values():
        assert ring["psnr_corrected"] == pytest.approx(ring["psnr_uncorrected"], abs=1e-4)


def test_onnx_for_another_domain_is_refused(tmp_path):
    from isp.errors import PlacementError
    from restoration.evaluate.runner import load_runner

    # camera_rgb (the slot), linear_rgb and display_rgb (the placement ablation) run; not others
    with pytest.raises(PlacementError, match="raw_linear"):
        load_runner(onnx_select_rgb(tmp_path / "d.onnx", {"domain": "raw_linear"}))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")     # the TorchScript exporter (no onnxscript here)
def test_checkpoint_and_onnx_score_alike(make, tmp_path):
    """Property (torch ↔ ONNX): a small DOConv UNet saved as a checkpoint
    and exported to ONNX gives the same metrics (±0.01 dB, ±1e-4 SSIM)."""
    torch = pytest.importorskip("torch")
    onnx = pytest.importorskip("onnx")
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.evaluate.rings import evaluate_plan
    from restoration.nn.network import build_model
    from restoration.evaluate.runner import TorchRunner, load_runner

    torch.manual_seed(0)
    kwargs = {"widths": [8, 8], "depths": [1, 0, 1]}
    model = build_model("doconv", **kwargs).eval()
    with torch.no_grad():                      # a visible correction, not the near-identity of an untrained head
        model.head[0].weight.mul_(20.0)
    meta = {"domain": "camera_rgb", "fov_encoding": "xy", "input_multiple": 4, "receptive_radius": 24,
            "lens": "toy"}
    ckpt = save_checkpoint(tmp_path / "m.pt", model, variant="doconv", model_kwargs=kwargs, metadata=meta)
    x = torch.rand(1, 5, 64, 64)
    path = tmp_path / "m.onnx"
    torch.onnx.export(model, (x,), str(path), dynamo=False, opset_version=17, input_names=["input"],
                      output_names=["output"], dynamic_axes={"input": {2: "h", 3: "w"}, "output": {2: "h", 3: "w"}})
    m = onnx.load(str(path))
    for k, v in meta.items():
        e = m.metadata_props.add()
        e.key, e.value = k, str(v)
    onnx.save(m, str(path))

    t_run, o_run = load_runner(ckpt), load_runner(path)
    assert isinstance(t_run, TorchRunner) and t_run.margin == 24 and t_run.meta["lens"] == "toy"
    plan, es = make([psf_map()], baseline="none")
    a = evaluate_plan(plan, t_run, es, executor=QUIET)
    b = evaluate_plan(plan, o_run, es, executor=QUIET)
    for k in ("0.1", "0.5", "0.9"):
        ra, rb = a["rings"][k], b["rings"][k]
        assert ra["psnr_corrected"] == pytest.approx(rb["psnr_corrected"], abs=0.01)
        assert ra["ssim_corrected"] == pytest.approx(rb["ssim_corrected"], abs=1e-4)
        assert abs(ra["psnr_corrected"] - ra["psnr_uncorrected"]) > 0.05     # the model does something


def test_a_checkpoint_whose_reach_exceeds_the_tile_runs_on_larger_tiles():
    """A receptive radius of 300 px with the default 512 px tile left no
    core (`isp eval` of a wide-attention model failed); the runner raises
    the tile instead, and the result is the whole-frame run's (tile 0)."""
    torch = pytest.importorskip("torch")
    from restoration.nn.network import build_model
    from restoration.evaluate.runner import MIN_CORE, TorchRunner

    torch.manual_seed(0)
    model = build_model("doconv", widths=(8, 8), depths=(0, 1, 0)).eval()
    run = TorchRunner(model, {"receptive_radius": 300, "tile_size": 512})
    assert run.tile >= 2 * 300 + MIN_CORE and run.tile % run.multiple == 0
    rgb = np.random.default_rng(0).random((40, 48, 3), dtype=np.float32)
    got = run(rgb, (0, 0), (40, 48))
    want = TorchRunner(model, {"receptive_radius": 300, "tile_size": 0})(rgb, (0, 0), (40, 48))
    assert np.abs(got - want).max() < 1e-5 and np.abs(got - rgb).max() > 1e-3
