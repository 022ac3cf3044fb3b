"""The optical-correction slot: runs an ONNX restoration model, or nothing.

Without a model the stage is the identity (and says so in the history).
With one, it reads the model's metadata (``domain``, ``placement``, ``lens``,
``tile_size``, ``fov_encoding``: written by ``isp export``) and refuses, when
the pipeline is built, a position whose domain differs from the one the
model was trained for, saying where it belongs. The model runs through
onnxruntime (never torch) with two intra-op threads.

Field-of-view encoding ``"xy"`` appends two channels holding each pixel's
normalised position on the *full* active area, in [-1, 1] (x right, y
down), so the model knows where in the field a pixel is even when it sees a
crop or a tile. (Tiling and the shipped model arrive with the export
issue; this stage runs the whole frame in one call.)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from isp.errors import ConfigError, PlacementError
from isp.frame import Domain, Frame
from isp.stage import StageBase

#: domains the slot can stand in (the model decides which one)
SLOT_DOMAINS = (Domain.RAW_LINEAR, Domain.CAMERA_RGB, Domain.LINEAR_RGB, Domain.DISPLAY_RGB)


def field_coordinates(shape: tuple[int, int], origin: tuple[int, int],
                      full_size: tuple[int, int]) -> np.ndarray:
    """Normalised field position of every pixel, (2, H, W) float32 in [-1, 1].

    Parameters
    ----------
    shape : (H, W)
        Size of the data (a crop or tile).
    origin : (row, col)
        Position of data[0, 0] in the full frame.
    full_size : (H, W)
        Size of the full frame (the active area).

    Returns
    -------
    ndarray; channel 0 = x (columns), 1 = y (rows); pixel centres, so the
    full frame's corner pixels sit just inside ±1.

    >>> field_coordinates((1, 2), (0, 0), (1, 2))[0]
    array([[-0.5,  0.5]], dtype=float32)
    """
    h, w = shape
    fh, fw = full_size
    ys = ((np.arange(h) + origin[0] + 0.5) / fh * 2.0 - 1.0).astype(np.float32)
    xs = ((np.arange(w) + origin[1] + 0.5) / fw * 2.0 - 1.0).astype(np.float32)
    out = np.empty((2, h, w), np.float32)
    out[0] = xs[None, :]
    out[1] = ys[:, None]
    return out


@dataclass(frozen=True)
class Correction(StageBase):
    """Optical-aberration correction by an ONNX model (identity without one).

    Parameters
    ----------
    model : path, optional
        ONNX file exported by ``isp export``; its metadata fixes the domain
        it must stand in.
    threads : int
        onnxruntime intra-op threads (the phone budget is 2).
    """

    name = "correction"
    consumes = SLOT_DOMAINS

    model: Path | None = None
    threads: int = 2

    def __post_init__(self):
        if self.threads < 1:
            raise ValueError(f"threads must be ≥ 1, got {self.threads}")
        if self.model is not None and not Path(self.model).is_file():
            raise ValueError(f"model file {str(self.model)!r} not found")

    @cached_property
    def session(self):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        try:
            return ort.InferenceSession(str(self.model), opts, providers=["CPUExecutionProvider"])
        except Exception as e:
            raise ConfigError(f"{self.model}: not a loadable ONNX model ({str(e)[:120]})") from None

    @cached_property
    def model_meta(self) -> dict[str, str]:
        """The model's custom metadata (empty without a model)."""
        if self.model is None:
            return {}
        return dict(self.session.get_modelmeta().custom_metadata_map)

    def check(self, domain: Domain) -> None:
        if self.model is None:
            return
        want = self.model_meta.get("domain")
        if want is None:
            raise PlacementError(f"model {self.model} has no 'domain' metadata; "
                                 "export it with `isp export` so its placement can be checked")
        if want != domain.value:
            where = self.model_meta.get("placement", f"where the data is {want}")
            raise PlacementError(
                f"model {Path(self.model).name} was trained for {want} data ({where}); "
                f"at this position the data is {domain.value}: move the correction stage there")

    def process(self, frame: Frame) -> Frame:
        if self.model is None:
            return frame.evolve(stage=self.name, note="identity (no model)")
        if frame.data.ndim != 3:
            raise ConfigError(f"correction model {self.model} expects 3-channel data, got a mosaic")
        x = np.ascontiguousarray(np.moveaxis(frame.data, -1, 0))[None]
        enc = self.model_meta.get("fov_encoding", "none")
        if enc == "xy":
            fov = field_coordinates(frame.data.shape[:2], frame.meta.origin, frame.full_size)
            x = np.concatenate([x, fov[None]], axis=1)
        inp = self.session.get_inputs()[0].name
        y = self.session.run(None, {inp: x.astype(np.float32, copy=False)})[0]
        out = np.ascontiguousarray(np.moveaxis(y[0], 0, -1), dtype=np.float32)
        lens = self.model_meta.get("lens", "?")
        return frame.evolve(out, stage=self.name, note=f"{Path(self.model).name} (lens {lens}, fov {enc})")
