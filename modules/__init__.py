"""The built-in stages, one module per stage (numpy/OpenCV; the correction
stage runs ONNX models, never torch).

Each module holds the stage's pure function(s) and a thin stage class with a
frozen dataclass of parameters; the classes reach the pipeline through the
``isp.stages`` entry points declared in ``pyproject.toml``. Helpers that
more than one stage uses live in :mod:`modules.common`.

May import: ``isp`` (frames, stages, errors), numpy, OpenCV,
colour-science, onnxruntime; never ``calibration``, ``restoration``,
``export`` or torch.
"""
