"""ONNX export and static INT8 quantization of the restoration network for
the ``correction`` stage (torch).

* :mod:`.onnx_export` — checkpoint → FP32 ONNX (opset ≥ 17, dynamic H/W),
  constant-weight check, torch ↔ ONNX parity, metadata, measured tile overlap;
* :mod:`.quantize` — static INT8 (QDQ), conv counts after ORT's
  optimisation, INT8 vs FP32 PSNR, mobile-usability checker;
* :mod:`.int8_form` — graph forms INT8 runs faster, and their inverses;
* :mod:`.cli` — ``isp export``.

May import: ``restoration`` (checkpoints and the network), ``modules`` (the
correction stage that runs the file), ``isp``, torch, onnx, onnxruntime.
"""
