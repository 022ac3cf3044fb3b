"""The optical-correction slot: runs an ONNX restoration model, or nothing.

A correction model is learned for one lens. By default (``model = "auto"``)
the stage runs the model of the lens profile that matches the frame's lens
identity (:mod:`isp.profiles`: UniqueCameraModel, Make, Model, LensModel of
``frame.meta``), and is the identity where no profile matches; its note in
the history (``isp process -v``) names the profile, or says why none
matched. ``model = FILE`` forces a model on every frame, ``"none"`` turns
the stage off (``isp process --correction FILE|none``).

Without a model the stage is the identity (and says so in the history).
With one, it reads the model's metadata (written by ``isp export``; table
below) and refuses, when the pipeline is built, a position whose domain
differs from the one the model was trained for, saying where it belongs.
The model runs through onnxruntime (never torch): one inter-op thread,
sequential execution, all graph optimisations; one session per model file
and thread count, shared by every stage that names it. A frame of several
tiles runs ``threads`` tiles at once, each on its own thread with one
intra-op thread (two whole-frame tiles side by side outrun one tile on two
threads, whose many short parallel sections wait on each other: 0.99 s
against 1.09 s for the packaged model on a 12 MP frame, 2 cores,
``benchmarks/correction.py``); a frame
of one tile runs on ``threads`` intra-op threads. The session loads on a
background thread as soon as the pipeline has the raw frame
(:meth:`Correction.prepare`), so onnxruntime's import and the graph's
optimisation (0.19 s for an e9 model) overlap the stages before the
slot.

Full frames run tile by tile (:mod:`modules.common.tiling`, crop-centre
stitching): each tile is read with a context margin of ``tile_overlap``
pixels on every side, the model runs on it, and only the tile's core is
kept, so with a margin at least the model's receptive-field radius the
stitched frame equals a whole-frame run (to float rounding; tested), and
the extra memory is the output frame plus one tile. Frame borders are
padded by reflection, in the whole-frame run as in the tiled one, by
``border_context`` pixels: the surround the model sees past the frame's
edge, which is made up alike in both runs and so need not be the seam
margin (:mod:`modules.common.tiling`).

Device calibration
------------------
A model with ``device_components = K`` reads one module's calibration, a
``device/v1`` file (:mod:`isp.io.device`): its descriptor, interpolated to
each pixel (or block centre) of the full frame, fills the K channels after
the field position. The file must be of the model's lens design and
descriptor basis (one line naming both otherwise). Without one the
descriptor is zero, the mean device of the design, and the stage's note
says so; a blind model ignores a device file, and says that too. Where the
file names its module's serial number (from its chart capture) and the
capture names its own (CameraSerialNumber), another module's file is refused
in one line: given the wrong module's calibration the model corrects some
modules worse than no correction at all (``docs/results/device.md``, "A
wrong calibration"). With the model chosen by the capture's lens profile
(``"auto"``), a profile that
has a ``device_model`` runs it where the module's calibration is known
(``--device``, the capture's own, the profile's) and its blind ``model``
everywhere else (:mod:`isp.profiles`).

Field-of-view encoding ``"xy"`` appends two channels holding each pixel's
normalised position on the *full* active area, in [-1, 1] (x right, y
down), computed per tile from the tile's position in the full frame (in
the reflected border margin, the position of the pixel that was mirrored
there, so the pair image/position stays one the model has seen).

Model contract
--------------
Inputs: the image ``(1, C, H, W)`` float32, ``C = 3`` (RGB in the slot's
domain) or ``5`` (RGB, field x, field y), ``H, W`` any multiple of
``input_multiple``; optionally ``stats`` (below). Output: ``(1, 3, H, W)``.
With ``space_to_depth = s`` the same, packed: ``(1, 3s² [+ 2], H/s, W/s)``
in, ``(1, 3s², H/s, W/s)`` out (:func:`pack_input`).
Quantised (QDQ INT8) and float models go through the same path; the
quantisation must be static (fixed scales), since a scale computed from
the input would differ between tiles.

========================  =========  ======================================================
metadata key              default    meaning
========================  =========  ======================================================
``domain``                required   domain the model was trained in (``camera_rgb`` ...)
``placement``             ""         where that is in the pipeline, for the error message
``lens``                  "?"        lens identity (reported in the history)
``fov_encoding``          "none"     ``"none"`` or ``"xy"`` (two field channels)
``tile_size``             512        tile side the model sees, margins included (px);
                                     ``0``: whole frame in one call
``tile_overlap``          see text   context margin per side (px); else
                                     ``receptive_radius`` (px), else ``receptive_field``
                                     (full width, px; margin = width // 2), else 32
``border_context``        margin     reflected context past the frame's edges (px), at most
                                     the margin: the float model's measured margin for an
                                     INT8 copy, whose own margin is set by rounding flips
``input_multiple``        4          H and W of every call are multiples of it, and tile
                                     origins too (a UNet's total stride)
``space_to_depth``        1          ``s > 1``: input and output packed ``s × s`` to depth
                                     (:func:`pack_input`, :func:`unpack_output`); the
                                     stage packs while it reads each tile
``device_components``     0          K > 0: a model for every device of a lens design; its
                                     input holds, after the field channels, the device's
                                     descriptor (``device/v1``) at each pixel, K channels
``device_design``         ""         the design's key a device file must name
``device_basis``          ""         the descriptor basis's key a device file must name
``attention``             "local"    ``"local"``: attention statistics from a bounded
                                     neighbourhood (tile-consistent, nothing to do);
                                     ``"global"``: pooled over the whole input, so the
                                     model must take them as a ``stats`` input;
                                     ``"field"``: from the field position (and the
                                     device's descriptor) alone, no image content
                                     (tile-consistent, nothing to do)
========================  =========  ======================================================

Attention statistics
--------------------
A model whose attention pools over its whole input would see different
statistics in every tile. Such a model (``attention = "global"``) exposes
the pooled statistics as a second input named ``stats``, shape ``(1, K)``
or ``(1, K, 1, 1)``; the stage computes them once per frame and feeds the
same value to every tile:

.. math::

    \\mathrm{stats}_k = \\frac{1}{H W} \\sum_{i, j} x_k(i, j),
    \\quad k < K \\in \\{3, 5\\}

the per-channel mean of the model's input over the frame it is given
(RGB, then the field channels when ``K = 5``), accumulated in float64
(an area-downscaled frame has the same mean). Training must feed the
mean of the same channels over the whole training image (``x.mean((2,
3))`` in torch). A ``"global"`` model without a ``stats`` input runs only
untiled (``tile_size = 0``), and the stage says so at build time. Any
model that declares a ``stats`` input gets it, whatever its ``attention``.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np

from isp.errors import ConfigError, IspError, PlacementError
from isp.frame import Domain, Frame, Step
from isp.stage import StageBase

from modules.common.tiling import plan_tiles, run_tiled

#: domains the slot can stand in (the model decides which one)
SLOT_DOMAINS = (Domain.RAW_LINEAR, Domain.CAMERA_RGB, Domain.LINEAR_RGB, Domain.DISPLAY_RGB)
#: defaults for absent metadata (see the module table)
DEFAULT_TILE_SIZE = 512
DEFAULT_OVERLAP = 32
DEFAULT_MULTIPLE = 4
FOV_ENCODINGS = ("none", "xy")
ATTENTION_MODES = ("local", "global", "field")
#: name of the optional frame-statistics input
STATS_INPUT = "stats"
_DTYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16}


def field_coordinates_at(rows: np.ndarray, cols: np.ndarray, full_size: tuple[int, int]) -> np.ndarray:
    """Normalised field position of the pixels ``rows × cols``, (2, h, w) float32.

    Parameters
    ----------
    rows, cols : (h,), (w,) int arrays
        Row and column of each pixel in the full frame (active area).
    full_size : (H, W)
        Size of the full frame.

    Returns
    -------
    ndarray; channel 0 = x (columns), 1 = y (rows), ``(i + ½) / N · 2 - 1``
    for pixel ``i`` of ``N``: in (-1, 1) on the frame.

    >>> field_coordinates_at(np.array([0]), np.array([0, 1]), (1, 2))[0]
    array([[-0.5,  0.5]], dtype=float32)
    """
    fh, fw = full_size
    ys = ((np.asarray(rows) + 0.5) / fh * 2.0 - 1.0).astype(np.float32)
    xs = ((np.asarray(cols) + 0.5) / fw * 2.0 - 1.0).astype(np.float32)
    out = np.empty((2, ys.size, xs.size), np.float32)
    out[0] = xs[None, :]
    out[1] = ys[:, None]
    return out


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
    return field_coordinates_at(np.arange(h) + origin[0], np.arange(w) + origin[1], full_size)


@functools.lru_cache(maxsize=4)
def _cached_session(path: str, mtime_ns: int, threads: int):
    import onnxruntime as ort

    try:
        return ort.InferenceSession(path, session_options(threads), providers=["CPUExecutionProvider"])
    except Exception as e:  # noqa: BLE001 — ORT's load errors share no base class but Exception
        raise ConfigError(f"{path}: not a loadable ONNX model ({str(e)[:120]})") from None


def session_options(threads: int = 2):
    """onnxruntime options of the stage: ``threads`` intra-op threads, one
    inter-op thread, sequential execution, every graph optimisation, and no
    spin-waiting.

    ORT's worker threads spin after each run by default; between tiles the
    stage's own thread (gathering the next tile, stitching the last) then
    competes with them for the two cores. Measured on a loaded 2-core
    machine, 12 MP in 63 tiles: 2.2–2.7 s CPU with spinning, 1.4–1.7 s
    without (``benchmarks/correction_tiling.py``)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    opts.add_session_config_entry("session.inter_op.allow_spinning", "0")
    return opts


#: one session loads at a time: a caller wanting the session a background
#: load (:func:`prefetch_session`) is making waits for it instead of making another
_SESSION_LOCK = threading.Lock()


def onnx_session(path: str | os.PathLike, threads: int = 2):
    """The onnxruntime session for a model file, created once per (file,
    modification time, threads) and shared (thread-safe)."""
    p = Path(path).resolve()
    with _SESSION_LOCK:
        return _cached_session(str(p), p.stat().st_mtime_ns, threads)


def prefetch_session(load: Callable[[], object]) -> threading.Thread:
    """Run ``load`` (which calls :func:`onnx_session`) on a daemon thread, so
    that the session is ready, or nearly, when the caller asks for it; any
    error is left for that call to raise (the load is made again there)."""
    def run():
        try:
            load()
        except Exception:   # noqa: BLE001 — reported by the stage's own call, in its words
            pass

    t = threading.Thread(target=run, name="onnx-prefetch", daemon=True)
    t.start()
    return t


@dataclass(frozen=True)
class ModelInfo:
    """What the stage needs to know about a model: its metadata (module
    table) and its declared inputs. Built by :func:`model_info`."""

    name: str
    meta: dict
    fov_encoding: str
    tile_size: int
    overlap: int
    multiple: int
    attention: str
    input_name: str
    in_channels: int
    dtype: type
    stats_name: str | None
    stats_shape: tuple[int, ...] | None
    packing: int = 1
    border: int | None = None   #: ``border_context`` (None: the overlap)
    device: int = 0             #: ``device_components``: descriptor channels after the field


class Tiling(NamedTuple):
    """How the stage cuts a frame (:mod:`modules.common.tiling`), in pixels."""

    tile: int      #: window side, context included (0: the whole frame)
    margin: int    #: context between tiles, per side
    multiple: int  #: window sides and tile origins are multiples of it
    border: int    #: reflected context past the frame's edges


def _int_meta(meta: dict, key: str, default: int, name: str, minimum: int = 0) -> int:
    v = meta.get(key)
    if v is None:
        return default
    try:
        i = int(str(v).strip())
    except ValueError:
        i = None
    if i is None or i < minimum:
        raise ConfigError(f"model {name}: metadata {key}={v!r} is not an integer ≥ {minimum}")
    return i


def _choice_meta(meta: dict, key: str, valid: tuple[str, ...], name: str) -> str:
    v = meta.get(key, valid[0])
    if v not in valid:
        raise ConfigError(f"model {name}: metadata {key}={v!r}; valid: {', '.join(map(repr, valid))}")
    return v


def model_info(session, name: str = "model") -> ModelInfo:
    """Parse a session's metadata and inputs (an onnxruntime session, or
    the file's :class:`~modules.common.onnx_header.ModelHeader`);
    ConfigError naming the key, value and valid choices on anything the
    stage cannot run."""
    meta = dict(session.get_modelmeta().custom_metadata_map)
    fov = _choice_meta(meta, "fov_encoding", FOV_ENCODINGS, name)
    attention = _choice_meta(meta, "attention", ATTENTION_MODES, name)
    if "tile_overlap" in meta:
        overlap = _int_meta(meta, "tile_overlap", DEFAULT_OVERLAP, name)
    elif "receptive_radius" in meta:
        overlap = _int_meta(meta, "receptive_radius", DEFAULT_OVERLAP, name)
    elif "receptive_field" in meta:
        overlap = _int_meta(meta, "receptive_field", DEFAULT_OVERLAP, name) // 2
    else:
        overlap = DEFAULT_OVERLAP
    inputs = session.get_inputs()
    images = [i for i in inputs if i.name != STATS_INPUT]
    stats = [i for i in inputs if i.name == STATS_INPUT]
    if len(images) != 1:
        raise ConfigError(f"model {name}: expected one image input (plus optional {STATS_INPUT!r}); "
                          f"got {[i.name for i in inputs]}")
    img = images[0]
    packing = _int_meta(meta, "space_to_depth", 1, name, minimum=1)
    multiple = _int_meta(meta, "input_multiple", DEFAULT_MULTIPLE, name, minimum=1)
    if multiple % packing:
        raise ConfigError(f"model {name}: metadata space_to_depth={packing} does not divide "
                          f"input_multiple={multiple}")
    device = _int_meta(meta, "device_components", 0, name)
    if device and fov != "xy":
        raise ConfigError(f"model {name}: metadata device_components={device} needs fov_encoding 'xy'")
    want = 3 * packing * packing + (2 if fov == "xy" else 0) + device
    if len(img.shape) != 4 or (isinstance(img.shape[1], int) and img.shape[1] != want):
        packed = f", packed {packing}×{packing} to depth" if packing > 1 else ""
        dev = f", {device} descriptor channels" if device else ""
        raise ConfigError(f"model {name}: input {img.name!r} has shape {img.shape}; with fov_encoding "
                          f"{fov!r}{packed}{dev} it must be (1, {want}, H, W)")
    if img.type not in _DTYPES:
        raise ConfigError(f"model {name}: input type {img.type}; valid: {', '.join(_DTYPES)}")
    stats_shape = None
    if stats:
        s = stats[0].shape
        k = s[1] if len(s) in (2, 4) and isinstance(s[1], int) else None
        if k not in (3, want):
            raise ConfigError(f"model {name}: input {STATS_INPUT!r} has shape {s}; expected (1, K) or "
                              f"(1, K, 1, 1) with K = 3 or {want}")
        stats_shape = (1, k) if len(s) == 2 else (1, k, 1, 1)
    return ModelInfo(
        name=name, meta=meta, fov_encoding=fov,
        tile_size=_int_meta(meta, "tile_size", DEFAULT_TILE_SIZE, name),
        overlap=overlap, multiple=multiple,
        attention=attention, input_name=img.name, in_channels=want, dtype=_DTYPES[img.type],
        stats_name=STATS_INPUT if stats else None, stats_shape=stats_shape, packing=packing,
        border=_int_meta(meta, "border_context", overlap, name) if "border_context" in meta else None,
        device=device)


def pack_input(x: np.ndarray, s: int) -> np.ndarray:
    """A model input ``(N, 3 [+ 2], H, W)`` packed ``s × s`` to depth:
    ``(N, 3s² [+ 2], H/s, W/s)``, channel ``(dy·s + dx)·3 + c`` = colour
    ``c`` of pixel ``(s·i + dy, s·j + dx)``, then the field channels
    averaged over each block (its centre's position, for a field linear in
    the pixel index). ``s = 1`` returns ``x``.

    >>> x = np.arange(2 * 5 * 2 * 2, dtype=np.float32).reshape(2, 5, 2, 2)
    >>> pack_input(x, 2).shape
    (2, 14, 1, 1)
    >>> np.array_equal(unpack_output(pack_input(x, 2)[:, :12], 2), x[:, :3])
    True
    """
    if s == 1:
        return x
    n, c, h, w = x.shape
    if h % s or w % s:
        raise ValueError(f"H, W = {h}, {w} must be multiples of {s}")
    rgb = x[:, :3].reshape(n, 3, h // s, s, w // s, s).transpose(0, 3, 5, 1, 2, 4)
    out = [rgb.reshape(n, 3 * s * s, h // s, w // s)]
    if c > 3:
        out.append(x[:, 3:].reshape(n, c - 3, h // s, s, w // s, s).mean(axis=(3, 5), dtype=np.float64))
    return np.ascontiguousarray(np.concatenate(out, axis=1), dtype=x.dtype)


def unpack_output(y: np.ndarray, s: int) -> np.ndarray:
    """Inverse of the RGB part of :func:`pack_input`: ``(N, 3s², h, w)`` →
    ``(N, 3, h·s, w·s)``."""
    if s == 1:
        return y
    n, c, h, w = y.shape
    k = c // (s * s)
    return np.ascontiguousarray(y.reshape(n, s, s, k, h, w).transpose(0, 3, 4, 1, 5, 2).reshape(n, k, h * s, w * s))


def run_model(session, x: np.ndarray, info: ModelInfo | None = None) -> np.ndarray:
    """One call of an exported model on an unpacked input ``(N, 3 [+ 2], H,
    W)`` → ``(N, 3, H, W)``, packing and unpacking as its metadata says
    (for tools and tests; the stage packs while it tiles)."""
    info = info or model_info(session)
    s = info.packing
    return unpack_output(session.run(None, {info.input_name: pack_input(x, s)})[0], s)


def frame_statistics(data: np.ndarray, channels: int, origin: tuple[int, int] = (0, 0),
                     full_size: tuple[int, int] | None = None) -> np.ndarray:
    """Per-channel mean of the model input over a whole frame (the
    ``stats`` input; module Notes).

    Parameters
    ----------
    data : (H, W, 3) float32
        The frame (or crop) the stage processes.
    channels : 3 or 5
        3: RGB means; 5: RGB then the mean field position (x, y).
    origin, full_size
        As for :func:`field_coordinates`.

    Returns
    -------
    (channels,) float32.
    """
    rgb = data.mean(axis=(0, 1), dtype=np.float64)
    if channels == 3:
        return rgb.astype(np.float32)
    h, w = data.shape[:2]
    fs = full_size or (h, w)
    f = field_coordinates_at(np.arange(h) + origin[0], np.arange(w) + origin[1], fs)
    xy = [f[0, 0].mean(dtype=np.float64), f[1, :, 0].mean(dtype=np.float64)]
    return np.concatenate([rgb, xy]).astype(np.float32)


#: the packaged models (``modules/models/``, provenance in its README.md)
MODELS_DIR = Path(__file__).parent / "models"
#: model names the stage resolves itself: the default phone lens's INT8 model
SHIPPED_MODELS = {"default": "e9_default.int8.onnx"}
#: ``model`` values that mean no model (the stage is the identity)
NO_MODEL = ("none", "")
#: the ``model`` value that picks, per frame, the model of the matching lens profile
AUTO = "auto"


def resolve_model(model: str | Path | None) -> Path | None:
    """The model file a ``model`` parameter names: ``"default"`` (or another
    key of :data:`SHIPPED_MODELS`) the packaged file, ``"none"``, ``""`` or
    None no model, anything else a path (``"auto"`` is resolved per frame,
    by :func:`isp.profiles.match_profile`, and is not accepted here).

    >>> resolve_model("none") is None
    True
    >>> resolve_model("default").name
    'e9_default.int8.onnx'
    """
    if model is None or (isinstance(model, str) and model.strip().lower() in NO_MODEL):
        return None
    if isinstance(model, str) and model.strip().lower() == AUTO:
        raise ValueError("model 'auto' names no file: it is the matching lens profile's, per frame")
    if isinstance(model, str) and model in SHIPPED_MODELS:
        return MODELS_DIR / SHIPPED_MODELS[model]
    return Path(model)


@dataclass(frozen=True)
class Correction(StageBase):
    """Optical-aberration correction by an ONNX model (identity without one).

    Parameters
    ----------
    model : "auto", path, "default" or "none"
        ``"auto"``: per frame, the model of the lens profile matching
        ``frame.meta`` (:func:`isp.profiles.match_profile`), none where no
        profile matches. A path: an ONNX file exported by ``isp export``,
        run on every frame; its metadata fixes the domain it must stand in,
        the tile size and the overlap (module table). ``"default"``: the
        packaged INT8 model of the default phone lens, on every frame
        (:data:`SHIPPED_MODELS`); ``"none"``: no model, the identity
        (``isp process --correction none``).
    threads : int
        Threads the model runs on (the phone budget is 2): that many tiles
        at once, one onnxruntime intra-op thread each, on a frame of several
        tiles; that many intra-op threads on a frame of one.
    tile_size : int, optional
        Override of the model's ``tile_size`` (px, margins included; 0: the
        whole frame in one call, memory growing with the frame).
    overlap : int, optional
        Override of the model's context margin per side (px).
    border : int, optional
        Override of the model's ``border_context`` (px; at most the
        margin): the reflected surround past the frame's edges.
    progress : bool, optional
        Progress bar on stderr; by default when stderr is a terminal and the
        frame takes at least 4 tiles.
    device : path or DeviceCalibration, optional
        The module's calibration (``device/v1``) for a model conditioned on
        it (module notes; ``isp process --device FILE``), a file or one
        read already (:class:`isp.io.device.DeviceCalibration`).
    """

    name = "correction"
    consumes = SLOT_DOMAINS

    model: str | Path | None = AUTO
    threads: int = 2
    tile_size: int | None = None
    overlap: int | None = None
    border: int | None = None
    progress: bool | None = None
    device: object = None       #: path or isp.io.device.DeviceCalibration

    def __post_init__(self):
        if self.threads < 1:
            raise ValueError(f"threads must be ≥ 1, got {self.threads}")
        if self.tile_size is not None and self.tile_size < 0:
            raise ValueError(f"tile_size must be ≥ 0 (0: whole frame), got {self.tile_size}")
        if self.overlap is not None and self.overlap < 0:
            raise ValueError(f"overlap must be ≥ 0, got {self.overlap}")
        if self.border is not None and self.border < 0:
            raise ValueError(f"border must be ≥ 0, got {self.border}")
        object.__setattr__(self, "_by_model", {})   # auto: the stage of each profile's model
        from isp.io.device import DeviceCalibration

        if isinstance(self.device, (str, os.PathLike)) and str(self.device).strip().lower() in NO_MODEL:
            object.__setattr__(self, "device", None)
        if self.device is not None and not isinstance(self.device, DeviceCalibration):
            DeviceCalibration.load(self.device)      # a bad file fails when the pipeline is built
        if isinstance(self.model, str) and self.model.strip().lower() == AUTO:
            object.__setattr__(self, "model", AUTO)
            return
        path = resolve_model(self.model)
        if path is not None and not path.is_file():
            shipped = " (the packaged default: reinstall the package)" if path.parent == MODELS_DIR else ""
            raise ValueError(f"model file {str(path)!r} not found{shipped}")
        object.__setattr__(self, "model", path)  # frozen: resolved once, here

    @property
    def auto(self) -> bool:
        """True when the model is chosen per frame by lens profile."""
        return self.model == AUTO

    @property
    def session(self):
        """The shared onnxruntime session on ``threads`` intra-op threads
        (:func:`onnx_session`)."""
        return onnx_session(self.model, self.threads)

    def tile_count(self, shape: tuple[int, int]) -> int:
        """Tiles of a frame of ``shape = (H, W)`` (:meth:`tiling`)."""
        tile, margin, mult, border = self.tiling()
        return len(plan_tiles(shape, tile, margin, mult, border))

    def workers(self, tiles: int) -> int:
        """Tiles run at once on a frame of ``tiles`` tiles: ``threads``, at
        most one per tile (module Notes)."""
        return max(1, min(self.threads, tiles))

    def tile_session(self, workers: int):
        """The session the tiles run on: one intra-op thread per worker's
        share of ``threads``."""
        return onnx_session(self.model, max(1, self.threads // workers))

    def prepare(self, frame: Frame) -> None:
        """Start loading the model's session on a background thread
        (:func:`prefetch_session`), for a frame the size of ``frame`` (the
        raw frame the pipeline starts from; the slot sees the same size),
        so that it overlaps the stages before the slot. Never raises: the
        slot's own run reports what is wrong."""
        try:
            stage = self.for_frame(frame.meta)[0] if self.auto else self
        except Exception:   # noqa: BLE001 — the slot's own run reports it, in its words
            return
        if stage.model is None:
            return
        prefetch_session(lambda: stage.tile_session(stage.workers(stage.tile_count(frame.data.shape[:2]))))

    def for_frame(self, meta) -> tuple["Correction", str]:
        """The stage that runs on a frame of metadata ``meta``, and why.

        Returns
        -------
        stage : Correction
            This stage with a fixed model: the matching profile's model
            (``"auto"``; its ``device_model`` where the module's calibration
            is known; the identity where none matches), else itself.
        reason : str
            One line: the profile and what it matched on, or why no profile
            matched ("" for a forced model or none).
        """
        if not self.auto:
            return self, ""
        from isp.profiles import match_profile

        found = match_profile(meta)
        prof = found.profile
        # the stage's own device (--device), then the capture's own (DNGPrivateData), then the profile's
        carried = bool(getattr(meta, "device_calibration", ""))
        device = self.device if self.device is not None or prof is None or carried else prof.device
        known = carried or device is not None
        # a module whose calibration is known gets the profile's conditioned model, where it has one
        path = None if prof is None else prof.device_model if known and prof.device_model else prof.model
        stage = self._by_model.get((path, device))
        if stage is None:
            try:
                stage = dataclasses.replace(self, model=path or "none", device=device)
            except (ValueError, IspError) as e:   # the profile's files went away after it was read
                raise ConfigError(f"lens profile {prof.name!r}: {e}") from None
            self._by_model[(path, device)] = stage
        return stage, found.reason()

    @cached_property
    def header(self):
        """The model file's metadata and inputs, read from the file itself
        (:mod:`modules.common.onnx_header`): checking a model when the
        pipeline is built needs no onnxruntime, whose session loads in the
        background (:meth:`prepare`)."""
        from modules.common.onnx_header import read_header

        return read_header(self.model)

    @cached_property
    def info(self) -> ModelInfo:
        return model_info(self.header, Path(self.model).name)

    @cached_property
    def model_meta(self) -> dict[str, str]:
        """The model's custom metadata (empty without a model, or with one
        chosen per frame)."""
        if self.model is None or self.auto:
            return {}
        return self.header.metadata

    def summary(self, meta=None) -> dict:
        """What ``isp info`` reports: the model in use, where it comes from,
        its lens, domain and size (``{"model": None}`` without one).

        With ``model = "auto"``, the model of the profile matching ``meta``
        (a CameraMeta) and the profile (``profile``, ``match``: the reason
        in one line), or ``{"model": None, ...}`` saying why none matched;
        without ``meta``, ``{"model": "auto", ...}``."""
        if self.auto:
            if meta is None:
                return {"model": AUTO, "note": "the model of the lens profile matching each file "
                                               "(`isp profiles`); none where no profile matches"}
            from isp.profiles import match_profile

            found = match_profile(meta)
            if found.profile is None:
                return {"model": None, "profile": None, "identity": found.identity,
                        "note": f"rendered without correction: {found.reason()}"}
            stage, _ = self.for_frame(meta)
            return {**stage.summary(), "profile": found.profile.name, "match": found.reason(),
                    "identity": found.identity}
        if self.model is None:
            return {"model": None, "note": "no correction model: the stage is the identity"}
        meta = self.model_meta
        packaged = self.model.parent == MODELS_DIR
        return {"model": self.model.name, "path": str(self.model),
                "source": "packaged default" if packaged else "user file",
                "lens": meta.get("lens", "?"), "domain": meta.get("domain"),
                "placement": meta.get("placement", ""), "precision": meta.get("precision", "?"),
                "size_kb": round(self.model.stat().st_size / 1024, 1),
                "training_data": meta.get("training_data", "?")}

    def tiling(self) -> Tiling:
        """Tile side, margin, multiple and border context in pixels, the
        stage's overrides applied to the model's metadata (the border at
        most the margin)."""
        i = self.info
        tile = i.tile_size if self.tile_size is None else self.tile_size
        margin = i.overlap if self.overlap is None else self.overlap
        border = self.border if self.border is not None else i.border if i.border is not None else margin
        return Tiling(tile, margin, i.multiple, min(border, margin))

    def check(self, domain: Domain) -> None:
        # "auto": the model is known per frame, and checked there (process)
        if self.model is None or self.auto:
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
        info = self.info
        tile, margin, mult, _ = self.tiling()
        if info.attention == "global" and info.stats_name is None and tile != 0:
            raise ConfigError(
                f"model {info.name} pools its attention over the whole input (metadata "
                f"attention='global') and has no {STATS_INPUT!r} input, so every tile would see "
                "different statistics: set tile_size = 0 (whole frame, memory grows with it) or "
                f"export it with local attention or a {STATS_INPUT!r} input")
        if tile:
            try:
                plan_tiles((tile, tile), tile, margin, mult)
            except ValueError as e:
                raise ConfigError(f"model {info.name}: {e}") from None

    def process(self, frame: Frame) -> Frame:
        if self.auto:
            stage, why = self.for_frame(frame.meta)
            if stage.model is None:
                return frame.evolve(stage=self.name, note=f"identity: {why}")
            try:
                stage.check(frame.domain)
            except ConfigError as e:
                raise type(e)(f"{why}: {e}") from None
            out = stage.process(frame)
            step = Step(self.name, f"{why}: {out.history[-1].note}")
            return dataclasses.replace(out, history=frame.history + (step,))
        if self.model is None:
            return frame.evolve(stage=self.name, note="identity (no model)")
        if frame.data.ndim != 3 or frame.data.shape[2] != 3:
            raise ConfigError(f"correction model {self.model} expects 3-channel data, "
                              f"got shape {frame.data.shape}")
        info = self.info
        tile, margin, mult, border = self.tiling()
        n = self.tile_count(frame.data.shape[:2])
        workers = self.workers(n)
        sess = self.tile_session(workers)
        origin, full = frame.meta.origin, frame.full_size
        feeds = {}
        if info.stats_name is not None:
            s = frame_statistics(frame.data, info.stats_shape[1], origin, full)
            feeds[info.stats_name] = s.reshape(info.stats_shape).astype(info.dtype)

        k, p = 3 * info.packing ** 2, info.packing
        cal, device_note = self.calibration(info, frame.meta)

        def run(x: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
            if info.fov_encoding == "xy":
                if p > 1:   # each block's centre: the mean of its pixels' (reflected) positions
                    rows, cols = rows.reshape(-1, p).mean(1), cols.reshape(-1, p).mean(1)
                x[k:k + 2] = field_coordinates_at(rows + origin[0], cols + origin[1], full)
                if info.device:
                    x[k + 2:] = 0.0 if cal is None else cal.field_map(rows + origin[0], cols + origin[1],
                                                                       full)[:info.device]
            return sess.run(None, {info.input_name: x[None], **feeds})[0][0]

        out = run_tiled(run, frame.data, tile=tile, margin=margin, multiple=mult, out_channels=3,
                        extra_channels=info.in_channels - k, dtype=info.dtype, packing=p,
                        progress=self.progress, desc=f"correction {info.name}", border=border,
                        workers=workers)
        lens = info.meta.get("lens", "?")
        how = (f"{n} tiles of {tile} px, overlap {margin} px" if n > 1 else "whole frame") + \
            (f", border {border} px" if n == 1 or border != margin else "")
        return frame.evolve(out, stage=self.name,
                            note=f"{info.name} (lens {lens}, fov {info.fov_encoding}, {how}){device_note}")

    def calibration(self, info: ModelInfo, meta=None):
        """The device calibration the model reads, and a note for the
        history: ``(DeviceCalibration or None, str)``. The stage's
        ``device``, else the one the frame's DNG carries
        (``meta.device_calibration``); ConfigError (one line) for one of
        another design or basis, or too short; InputError (one line) for
        another module's, where both the calibration and the capture name
        their module's serial number."""
        from isp.io.device import DeviceCalibration

        carried = getattr(meta, "device_calibration", "") if self.device is None else ""
        if self.device is None and not carried:
            return None, ("; no device calibration: the design's mean device (descriptor 0)"
                          if info.device else "")
        if carried:
            name = f"{Path(meta.path).name if meta.path else 'the file'}'s own (DNGPrivateData)"
            cal = DeviceCalibration.from_text(carried, name)
        elif isinstance(self.device, DeviceCalibration):
            cal = self.device
            name = cal.source.get("name") or cal.source.get("measured") or "calibration"
        else:
            cal, name = DeviceCalibration.load(self.device), Path(self.device).name
        if not info.device:
            return None, f"; {name} ignored: the model is not conditioned on a device"
        cal.check_model(info.meta, info.device, name, f"model {info.name}")
        if meta is not None:
            cal.check_module(getattr(meta, "serial", ""), name, meta.path or "the capture")
        return cal, f"; device {name}"
