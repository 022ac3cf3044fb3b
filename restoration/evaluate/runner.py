"""Run a correction model on a crop of the sensor: a torch checkpoint
(``restoration.nn.checkpoint``) or an exported ONNX file, through one
interface, so the evaluation treats them alike.

A runner is called as ``runner(rgb, origin, full_size)``: ``rgb`` an
``(h, w, 3)`` float32 crop of balanced camera RGB (the correction slot's
input, :class:`isp.frame.Domain` ``camera_rgb``) whose first pixel is
sensor pixel ``origin``, on a frame of ``full_size``; it returns the
corrected ``(h, w, 3)`` float32 crop. A model conditioned on the device
reads the runner's ``device`` (a :class:`isp.io.device.DeviceCalibration`,
or None: descriptor 0), as the stage reads ``--device``.

Both kinds run through the correction stage's execution path: the ONNX
runner *is* :class:`modules.correction.Correction` (onnxruntime, 2
threads, tiles of the model's ``tile_size`` with crop-centre stitching,
reflected borders, field channels of each window's pixels on the full
frame); the torch runner feeds the same windows
(:func:`modules.common.tiling.run_tiled`, same tile size, margin and multiple,
field channels from :func:`modules.correction.field_coordinates_at`) to the
torch model. So a checkpoint and its ONNX export see identical inputs and
their evaluations differ only by float rounding (tested).
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np

from isp.errors import ConfigError, InputError, IspError

__all__ = ["OnnxRunner", "Runner", "TorchRunner", "load_runner"]

#: domain every runner here is evaluated in (the synthesised slot input)
DOMAIN = "camera_rgb"
#: domains a runner may take: the slot's, the end of the pipeline (a model
#: trained sRGB → sRGB, the placement ablation; the evaluation feeds it the
#: processed input) or linear sRGB after the colour matrix (the placement
#: ablation's "linear"; fed the input through luminance and ccm)
DOMAINS = (DOMAIN, "display_rgb", "linear_rgb")


class Runner(Protocol):
    kind: str
    meta: dict

    def __call__(self, rgb: np.ndarray, origin: tuple[int, int], full_size: tuple[int, int]) -> np.ndarray: ...


def _frame_meta(origin, full_size):
    from isp.meta import CameraMeta

    h, w = (int(v) for v in full_size)
    return CameraMeta(origin=(int(origin[0]), int(origin[1])), active_area=(0, 0, h, w), raw_size=(h, w))


class OnnxRunner:
    """An exported model run by the correction stage itself.

    Parameters
    ----------
    path : path
        ``.onnx`` file with the stage's metadata (``domain`` must be
        ``camera_rgb``).
    threads : int
        onnxruntime intra-op threads (the stage's default 2).
    """

    kind = "onnx"

    def __init__(self, path, threads: int = 2, device=None):
        from isp.frame import Domain
        from modules.correction import Correction

        self.path = Path(path)
        try:
            self.stage = Correction(model=self.path, threads=threads, progress=False, device=device)
        except ValueError as e:
            raise InputError(self.path, str(e)) from None
        domain = self.stage.model_meta.get("domain", DOMAIN)
        self.domain = Domain(domain if domain in DOMAINS else DOMAIN)
        self.stage.check(self.domain)                 # PlacementError naming where it belongs
        tile, margin, mult, border = self.stage.tiling()
        info = self.stage.info
        self.meta = {**info.meta, "fov_encoding": info.fov_encoding, "tile_size": tile, "tile_overlap": margin,
                     "input_multiple": mult, "border_context": border}
        self.stage.calibration(info)                  # a device file of another design fails here

    @property
    def device(self):
        return self.stage.device

    def __call__(self, rgb, origin, full_size):
        from isp.frame import Frame

        frame = Frame(np.ascontiguousarray(rgb, dtype=np.float32), self.domain, _frame_meta(origin, full_size))
        return self.stage.process(frame).data


def _info_get(info, key, default=None):
    if isinstance(info, dict):
        return info.get(key, default)
    return getattr(info, key, default)


#: the least core (px) a checkpoint's tiles keep inside their margins; a
#: ``tile_size`` that leaves less is raised to keep it
MIN_CORE = 256


class TorchRunner:
    """A torch model (eval mode, CPU, no gradients) on the correction
    stage's windows.

    Parameters
    ----------
    model : torch.nn.Module
        Input ``(1, 3 or 5, H, W)`` (RGB, field x, field y), output
        ``(1, 3, H, W)``.
    info : dict, optional
        What :func:`restoration.nn.checkpoint.load_model` returns (its
        ``metadata`` entries read as top-level keys): ``fov_encoding`` (``"xy"``/``"none"``; default
        the model's attribute, else from its input channels),
        ``input_multiple`` (default the model's attribute, else 4),
        ``tile_size`` (default 512; raised where it would keep less than
        :data:`MIN_CORE` px inside the margins), ``tile_overlap`` or
        ``receptive_radius`` (default 32), ``domain``, ``lens``.
    path : path, optional
        Where it was read from (for the report).
    device : DeviceCalibration, optional
        For a model conditioned on the device (``model.device = K``): the
        descriptor its K channels after the field hold (None: 0).
    """

    kind = "checkpoint"

    def __init__(self, model, info=None, path=None, device=None):
        from modules.correction import (
            DEFAULT_MULTIPLE,
            DEFAULT_OVERLAP,
            DEFAULT_TILE_SIZE,
            FOV_ENCODINGS,
        )

        info = dict(info) if isinstance(info, dict) else {}
        self.info = info
        info = {**info, **(info.get("metadata") or {})}    # restoration.nn.checkpoint keeps them apart
        self.model = model.eval()
        self.path = Path(path) if path is not None else None
        self.k_device = int(getattr(model, "device", 0))
        self.device = device
        if device is not None and self.k_device:
            device.check_model(info, self.k_device, "the device calibration", f"model {self.path or ''}")
        domain = _info_get(info, "domain")
        if domain not in (None, *DOMAINS):
            raise ConfigError(f"model {self.path or ''} was trained for {domain} data; the evaluation "
                              f"runs models on {' or '.join(DOMAINS)} data")
        fov = _info_get(info, "fov_encoding") or getattr(model, "fov_encoding", None)
        if fov is None:
            fov = "xy" if getattr(model, "in_channels", 3) == 5 else "none"
        if fov not in FOV_ENCODINGS:
            raise ConfigError(f"fov_encoding {fov!r}; valid: {', '.join(FOV_ENCODINGS)}")
        self.fov_encoding = fov
        self.multiple = int(_info_get(info, "input_multiple") or getattr(model, "input_multiple", DEFAULT_MULTIPLE))
        tile = _info_get(info, "tile_size")
        self.tile = DEFAULT_TILE_SIZE if tile is None else int(tile)
        overlap = _info_get(info, "tile_overlap")
        if overlap is None:
            overlap = _info_get(info, "receptive_radius")
        self.margin = DEFAULT_OVERLAP if overlap is None else int(overlap)
        if 0 < self.tile < 2 * self.margin + MIN_CORE:
            # a network that reads far (a wide attention window) still runs: larger tiles, same result
            self.tile = -(-(2 * self.margin + MIN_CORE) // self.multiple) * self.multiple
        self.meta = {"fov_encoding": fov, "input_multiple": self.multiple, "tile_size": self.tile,
                     "tile_overlap": self.margin, "lens": _info_get(info, "lens"),
                     "domain": domain or DOMAIN}
        for key in ("variant", "epoch", "step", "training_data", "val_psnr_db", "placement", "process"):
            v = _info_get(info, key)
            if v is not None:
                self.meta[key] = v

    def __call__(self, rgb, origin, full_size):
        import torch

        from modules.correction import field_coordinates_at
        from modules.common.tiling import run_tiled

        extra = 2 + self.k_device if self.fov_encoding == "xy" else 0
        cal = self.device if self.k_device else None

        def run(x, rows, cols):
            if extra:
                x[3:5] = field_coordinates_at(rows + origin[0], cols + origin[1], full_size)
                if self.k_device:
                    x[5:] = 0.0 if cal is None else cal.field_map(rows + origin[0], cols + origin[1],
                                                                  full_size)[:self.k_device]
            with torch.inference_mode():
                y = self.model(torch.from_numpy(x[None].copy()))
            return y[0].detach().cpu().numpy().astype(np.float32, copy=False)

        return run_tiled(run, np.ascontiguousarray(rgb, dtype=np.float32), tile=self.tile, margin=self.margin,
                         multiple=self.multiple, out_channels=3, extra_channels=extra, progress=False)


def load_runner(path, *, threads: int = 2, device=None) -> Runner:
    """The runner of a model file: ``.onnx`` through onnxruntime, anything
    else as a checkpoint (:func:`restoration.nn.checkpoint.load_model`).

    Raises
    ------
    InputError
        Missing or unreadable file.
    ConfigError
        A model for another domain, or checkpoint support unavailable.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such model file (a checkpoint or an .onnx export)")
    if p.is_dir():
        raise InputError(p, "is a folder, not a model file")
    if p.suffix.lower() == ".onnx":
        return OnnxRunner(p, threads=threads, device=device)
    try:
        from restoration.nn.checkpoint import load_model
    except ImportError as e:
        raise ConfigError(f"{p}: reading checkpoints needs torch and restoration.nn.checkpoint ({e}); "
                          "or give an exported .onnx file") from None
    try:
        model, info = load_model(p)
    except IspError:
        raise
    except Exception as e:  # noqa: BLE001 — torch.load's errors share no base class
        raise InputError(p, f"not a loadable checkpoint ({type(e).__name__}: {str(e)[:120]})") from None
    return TorchRunner(model, info, p, device=device)
