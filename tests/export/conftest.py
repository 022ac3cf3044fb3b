"""Fixtures of the export tests (export/): a tiny exported model and its
INT8 copy, module-wide.

Fixtures
--------
exported
    (folder, model, report): a tiny DOConv UNet saved as ``tiny.pt`` and
    exported to ``tiny.onnx`` in that folder.
quantized
    The report of quantising ``tiny.onnx`` to ``tiny.int8.onnx``.
"""

from __future__ import annotations

import pytest

from tests.helpers import EXPORT_KW as KW
from tests.helpers import EXPORT_META as META
from tests.helpers import onnx_calibration_reader


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A tiny DOConv UNet (its head scaled away from the identity) saved as
    a checkpoint and exported to ONNX: (folder, model in eval mode, the
    export's report)."""
    torch = pytest.importorskip("torch")
    from export.onnx_export import export_onnx
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model

    d = tmp_path_factory.mktemp("export")
    torch.manual_seed(3)
    model = build_model("doconv", **KW)
    with torch.no_grad():  # away from the identity, so parity and quantisation see a real correction
        model.head[0].weight.mul_(10)
    ckpt = save_checkpoint(d / "tiny.pt", model, variant="doconv", model_kwargs=KW, step=5, metadata=META)
    report = export_onnx(ckpt, d / "tiny.onnx", tile_size=256)
    return d, model.eval(), report


@pytest.fixture(scope="module")
def quantized(exported):
    """The exported model quantised to static INT8 (``tiny.int8.onnx``
    beside it): the quantisation's report."""
    from export.quantize import quantize_int8

    d = exported[0]
    return quantize_int8(d / "tiny.onnx", d / "tiny.int8.onnx", onnx_calibration_reader())
