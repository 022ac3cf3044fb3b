"""ONNX export of a restoration checkpoint for the ``correction`` stage.

:func:`export_onnx` rebuilds the model of a checkpoint
(:func:`restoration.nn.checkpoint.load_model`), exports it with the
TorchScript exporter (opset ≥ 17, dynamic ``H`` and ``W``), checks that
every ``Conv`` has constant weights (initializers or ``Constant`` nodes:
what static INT8 can quantise), writes the metadata the correction stage
reads (:mod:`modules.correction`, table below), measures the torch ↔ ONNX
parity and the tile overlap the stage needs, and writes the file
atomically.

==================  =========================================================
metadata key        value
==================  =========================================================
``domain``          from the checkpoint (``camera_rgb``)
``placement``       from the checkpoint (``camera_rgb after demosaic``)
``lens``            from the checkpoint
``fov_encoding``    ``"xy"`` (RGB + field x, y) or ``"none"``
``tile_size``       tile side in px, margins included (``--tile-size``)
``tile_overlap``    context margin per side in px, *measured*
                    (:func:`measure_tile_overlap`); else ``receptive_radius``
``receptive_radius`` gradient-measured radius (px; an upper bound)
``border_context``  reflected surround past the frame's edges (px): the
                    float model's measured ``tile_overlap``, kept by its
                    INT8 copy (module Notes)
``input_multiple``  4 (the UNet's total stride)
``attention``       ``"local"``, ``"global"`` or ``"field"``
``device_components`` K of a network conditioned on the device (absent: blind)
``device_design``   the lens design's key (from the training sets' descriptors)
``device_basis``    the descriptor basis's key
``training_data``   the synth manifests' ``data_sha256`` (comma-joined)
``precision``       ``fp32`` (``int8`` after :func:`export.quantize.quantize_int8`)
``producer``        ``isp export`` + variant, training step, torch version
==================  =========================================================

Tile overlap
------------
The gradient-measured receptive radius (62 px for the packaged model) is a
bound: the influence of far pixels decays long before it, in float. The overlap
written is the smallest candidate margin ``m`` for which the stage's own
tiled run (:class:`modules.correction.Correction`, tiles of
``2 m + 128`` px) differs from its
whole-frame run with the same margin (so the same reflected border) by at
most ``tolerance`` on a smooth random input with edges and noise
(:func:`sample_frame`), 512 × 704 px so that every candidate cuts it into
several tiles. The difference is taken as the export issue's deliverable
states it: in 8-bit DN of the output encoded by the sRGB curve (the darks
weigh most), at most 0.5 DN by default, half the deliverable's 1 DN. It is
measured once, on one input: a property of the trained weights, so
re-export after training. An INT8 copy is measured on its own
(:func:`measure_tile_overlap` on the quantised file): a context change
that moves an activation across a rounding step moves the output by a
whole step of the residual's quantisation, so INT8 needs more margin than
its float model: for an e9 model with a 98 px receptive radius, 80 px
against 32; at 32 px its INT8 tiles differed from the whole frame by up
to 5.7 DN on a photograph, the float ones by 0.3 (``python -m
benchmarks.seams``), and at 80 px, short of its radius, still 2.5 DN on
512-px tiles, whose many seams met rare flips that the sample had not. So an INT8 file's
margin is at least its receptive radius (:func:`remeasure_overlap`):
integer arithmetic then makes its tiles the whole frame's result bit for
bit (the package: 64 px for a 62 px radius; 0.0 DN).

The surround the stage reflects past the frame's edges (``border_context``)
is not a seam: the whole-frame run makes it up as the tiles do. What it
must give is enough plausible context that the border pixels do not feel
the zero padding beyond, a property of the function, which the float
model's margin measures (the influence of far pixels there is within the
tolerance); an INT8 copy keeps its float model's value, where its own
margin would only re-round its quantisation noise, which it carries
everywhere. On the packaged model that is 32 px against the INT8 margin's
64, and INT8 computes 3.4 % fewer pixels on a 12 MP frame in 2,048-px tiles.
"""

from __future__ import annotations

import io
import json
import tempfile
import time
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from isp.errors import ConfigError, IspError

__all__ = [
    "METADATA_KEYS",
    "ExportError",
    "check_constant_weights",
    "export_onnx",
    "measure_tile_overlap",
    "onnx_parity",
    "op_counts",
    "prune_dead_nodes",
    "remeasure_overlap",
    "sample_frame",
    "set_metadata",
    "srgb_dn",
]

#: keys written into every exported model (module table)
METADATA_KEYS = ("domain", "placement", "lens", "fov_encoding", "tile_size", "tile_overlap", "receptive_radius",
                 "border_context", "input_multiple", "attention", "training_data", "precision", "producer")
MIN_OPSET = 17
#: margins tried by :func:`measure_tile_overlap` (px)
OVERLAP_CANDIDATES = (16, 24, 32, 40, 48, 56, 64, 80, 96, 128)
#: the tiled output's largest difference from the whole frame's allowed, in
#: DN of the 8-bit sRGB-encoded output (half the export issue's 1 DN)
OVERLAP_TOLERANCE = 0.5
#: torch ↔ ONNX FP32 parity required (max abs, linear camera RGB)
PARITY_TOLERANCE = 1e-4


class ExportError(IspError):
    """The model cannot be exported as the correction stage needs it."""


def op_counts(model) -> dict[str, int]:
    """Nodes per op type of an ``onnx.ModelProto`` (sorted by name)."""
    return dict(sorted(Counter(n.op_type for n in model.graph.node).items()))


def prune_dead_nodes(model) -> int:
    """Remove the nodes whose outputs nothing reads (not a graph output
    either), repeatedly; returns how many. ONNX Runtime runs them all the
    same: :func:`export.quantize.bypass_input_qdq` leaves such
    ``QuantizeLinear`` → ``DequantizeLinear`` pairs behind where it rewired
    their only reader, and :mod:`export.int8_form` the slices it replaced."""
    graph_outputs = {o.name for o in model.graph.output}
    removed = 0
    while True:
        read = {i for n in model.graph.node for i in n.input} | graph_outputs
        dead = [n for n in model.graph.node if not any(o in read for o in n.output)]
        if not dead:
            return removed
        for n in dead:
            model.graph.node.remove(n)
        removed += len(dead)


def check_constant_weights(model) -> int:
    """Check that every ``Conv`` of a float ONNX model reads its weight (and
    bias) from an initializer or a ``Constant`` node (through ``Identity``
    aliases, which the exporter inserts for shared initializers).

    Returns
    -------
    int : the number of Conv nodes.

    Raises
    ------
    ExportError
        Naming the convs whose weights are computed (a per-image weight, as
        in ODConv's usual form, stays float under static INT8).
    """
    g = model.graph
    const = {i.name for i in g.initializer} | {o for n in g.node if n.op_type == "Constant" for o in n.output}
    alias = {n.output[0]: n.input[0] for n in g.node if n.op_type == "Identity"}

    def resolve(name):
        seen = set()
        while name in alias and name not in seen:
            seen.add(name)
            name = alias[name]
        return name

    convs = [n for n in g.node if n.op_type == "Conv"]
    bad = [n.name or n.output[0] for n in convs
           if any(resolve(v) not in const for v in list(n.input[1:3]) if v)]
    if bad:
        raise ExportError(f"{len(bad)} of {len(convs)} Conv nodes have computed (non-constant) weights, "
                          f"which static INT8 leaves in float: {', '.join(bad[:5])}"
                          + (" ..." if len(bad) > 5 else "") + "; export a constant-weight variant")
    return len(convs)


def set_metadata(model, meta: dict) -> None:
    """Replace the model's ``metadata_props`` entries for ``meta``'s keys
    (values as strings; dicts and lists as JSON)."""
    text = {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.items() if v is not None}
    keep = [p for p in model.metadata_props if p.key not in text]
    del model.metadata_props[:]
    for p in keep:
        model.metadata_props.add(key=p.key, value=p.value)
    for k, v in text.items():
        model.metadata_props.add(key=k, value=v)


def sample_frame(shape: tuple[int, int], fov: bool, seed: int = 0) -> np.ndarray:
    """A "random-ish" camera-RGB frame, (H, W, 3) float32 in about [0, 1]:
    smooth random shading, a few hard-edged rectangles and a little noise
    (what a blur-correction model has to work on), plus, with ``fov``,
    nothing else (the stage computes the field channels)."""
    import cv2

    rng = np.random.default_rng(seed)
    h, w = shape
    low = cv2.resize(rng.random((max(2, h // 32), max(2, w // 32), 3), dtype=np.float32), (w, h),
                     interpolation=cv2.INTER_CUBIC)
    img = 0.15 + 0.6 * low
    for _ in range(8):
        y0, x0 = rng.integers(0, h - 8), rng.integers(0, w - 8)
        y1, x1 = y0 + rng.integers(8, h // 3), x0 + rng.integers(8, w // 3)
        img[y0:y1, x0:x1] = rng.random(3, dtype=np.float32) * 0.9
    img += rng.normal(0, 0.01, img.shape).astype(np.float32)
    return np.ascontiguousarray(img, dtype=np.float32)


def model_input(img: np.ndarray, fov: bool, device: int = 0, seed: int = 0) -> np.ndarray:
    """(1, C, H, W) float32 from (H, W, 3): RGB, then the full-frame field,
    then ``device`` descriptor channels: a random 5 × 7 descriptor of unit
    spread (seeded) interpolated as the stage does
    (:func:`isp.io.device.descriptor_map`)."""
    from modules.correction import field_coordinates

    x = img.transpose(2, 0, 1)
    if fov:
        x = np.concatenate([x, field_coordinates(img.shape[:2], (0, 0), img.shape[:2])])
    if device:
        from isp.io.device import descriptor_map

        d = np.random.default_rng(seed).normal(size=(5, 7, device))
        h, w = img.shape[:2]
        x = np.concatenate([x, descriptor_map(d, np.arange(h), np.arange(w), (h, w))])
    return np.ascontiguousarray(x[None], dtype=np.float32)


def _session(model_bytes_or_path, threads: int = 2):
    import onnxruntime as ort

    from modules.correction import session_options

    src = model_bytes_or_path if isinstance(model_bytes_or_path, bytes) else str(model_bytes_or_path)
    return ort.InferenceSession(src, session_options(threads), providers=["CPUExecutionProvider"])


def onnx_parity(model, session, sizes=((64, 96), (96, 128)), seed: int = 0) -> float:
    """Max abs difference, torch vs ONNX Runtime, over test inputs of ``sizes``
    (dynamic H, W exercised); the torch model in float32 eval mode, on
    unpacked inputs (a packed export is packed and unpacked by
    :func:`modules.correction.run_model`, so the repacking is checked too)."""
    import torch

    from modules.correction import run_model

    fov = getattr(model, "fov_encoding", "none") == "xy"
    err = 0.0
    for k, size in enumerate(sizes):
        x = model_input(sample_frame(size, fov, seed + k), fov, _device_channels(model), seed + k)
        with torch.no_grad():
            ref = model(torch.from_numpy(x)).numpy()
        got = run_model(session, x)
        if got.shape != ref.shape:
            raise ExportError(f"ONNX output shape {got.shape} differs from torch's {ref.shape} at input {size}")
        err = max(err, float(np.abs(got - ref).max()))
    return err


def srgb_dn(x: np.ndarray) -> np.ndarray:
    """Linear values (clipped to [0, 1]) as 8-bit sRGB code values, unrounded
    (IEC 61966-2-1 curve × 255).

    >>> srgb_dn(np.array([0.0, 0.0031308, 0.2140, 1.0])).round(2).tolist()
    [0.0, 10.31, 127.49, 255.0]
    """
    from modules.gamma import srgb_oetf

    return 255.0 * srgb_oetf(np.asarray(x, dtype=np.float64))


def measure_tile_overlap(path, candidates=OVERLAP_CANDIDATES, tolerance: float = OVERLAP_TOLERANCE,
                         shape: tuple[int, int] = (512, 704), seed: int = 0) -> dict:
    """Smallest margin at which the correction stage's tiled output matches
    its whole-frame output within ``tolerance`` (module Notes).

    Parameters
    ----------
    path : path
        The exported model (its metadata must let the stage load it).
    candidates : ints
        Margins tried, in px, ascending.
    tolerance : float
        Max abs difference allowed, in DN of the sRGB-encoded 8-bit output
        (:func:`srgb_dn`).
    shape : (H, W)
        Test frame size.

    Returns
    -------
    dict: ``overlap`` (px, or None when no candidate meets the tolerance),
    ``errors`` {margin: max abs difference}, ``tolerance``, ``shape``,
    ``tile`` {margin: tile side used}.
    """
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction

    img = sample_frame(shape, True, seed)
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=shape, active_area=(0, 0, *shape))
    frame = Frame(img, Domain.CAMERA_RGB, meta)
    errors, tiles, found = {}, {}, None
    for m in sorted(candidates):
        tile = 2 * m + 128
        # the reference is padded by reflection with the same margin (modules.common.tiling)
        whole = Correction(model=Path(path), tile_size=0, overlap=m).process(frame).data
        out = Correction(model=Path(path), tile_size=tile, overlap=m).process(frame).data
        errors[m], tiles[m] = float(np.abs(srgb_dn(out) - srgb_dn(whole)).max()), tile
        if errors[m] <= tolerance:
            found = m
            break
    return {"overlap": found, "errors": errors, "tile": tiles, "tolerance": tolerance, "shape": list(shape)}


def remeasure_overlap(path) -> dict:
    """Measure the tile overlap of a written model, an INT8 copy say
    (:func:`measure_tile_overlap`), and write it into the file's
    ``tile_overlap`` (its ``receptive_radius`` where no candidate keeps the
    tolerance; for an INT8 file at least its receptive radius, which makes
    its tiles exact: ``overlap_int8`` in the result). Returns the
    measurement. A model with global attention is left as it is (its tiles
    never match)."""
    import onnx

    from isp.io.files import atomic_path

    proto = onnx.load(str(path))
    measured = _measure_into(proto, path)
    if "note" not in measured:                      # global attention: nothing was written
        with atomic_path(Path(path)) as tmp:
            onnx.save(proto, str(tmp))
    return measured


def _measure_into(proto, path) -> dict:
    """Measure the overlap of ``path`` (a file holding ``proto``) and write it
    into ``proto``'s metadata, the receptive radius (with a warning) where
    no candidate keeps the tolerance; a global-attention model is left as
    it is."""
    meta = {p.key: p.value for p in proto.metadata_props}
    if meta.get("attention") == "global":
        return {"overlap": None, "note": "global attention: tiles never match; stage runs whole frames"}
    measured = measure_tile_overlap(path)
    if measured["overlap"] is None:
        warnings.warn(f"no margin up to {max(OVERLAP_CANDIDATES)} px keeps tiles within {OVERLAP_TOLERANCE:g} DN; "
                      f"tile_overlap = receptive_radius {meta.get('receptive_radius')}", stacklevel=3)
    radius = int(meta.get("receptive_radius", 0))
    margin = measured["overlap"] or radius
    if meta.get("precision") == "int8" and radius:
        # integer arithmetic: a tile whose margin covers the receptive radius is the whole frame's
        # result bit for bit, and one short of it leaves rare rounding flips that a sample can miss
        # (80 px of a 98 px radius: 0.23 DN on 1,024-px tiles, 2.5 DN on 512-px ones:
        # python -m benchmarks.seams)
        m = int(meta.get("input_multiple", 1)) or 1
        margin = max(margin, -(-radius // m) * m)
        measured["overlap_int8"] = margin
    # the first measurement (the float model's) also sets the surround past the frame's edges
    set_metadata(proto, {"tile_overlap": str(margin),
                         **({} if "border_context" in meta else {"border_context": str(margin)})})
    return measured


def _device_channels(model) -> int:
    """Descriptor channels a (space-to-depth form of a) network reads."""
    return int(getattr(getattr(model, "model", model), "device", 0))


def _export_bytes(model, opset: int, packing: int = 1) -> bytes:
    import torch

    from modules.correction import pack_input

    fov = getattr(model, "fov_encoding", "none") == "xy"
    x = torch.from_numpy(pack_input(model_input(sample_frame((64, 96), fov), fov, _device_channels(model)), packing))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation and constant-folding notes
        # dynamo=False: the torch.export-based exporter needs onnxscript (not a dependency)
        torch.onnx.export(model, (x,), buf, dynamo=False, opset_version=opset, input_names=["input"],
                          output_names=["output"],
                          dynamic_axes={"input": {2: "height", 3: "width"}, "output": {2: "height", 3: "width"}})
    return buf.getvalue()


def export_onnx(checkpoint, out_path, *, opset: int = MIN_OPSET, tile_size: int = 512,
                measure_overlap: bool = True, overlap: int | None = None,
                parity_tolerance: float = PARITY_TOLERANCE, packed: bool = True) -> dict:
    """Export a checkpoint to an ONNX model for the ``correction`` stage.

    Parameters
    ----------
    checkpoint : path
        A restoration checkpoint (:mod:`restoration.nn.checkpoint`).
    out_path : path
        The ``.onnx`` file to write (atomically; parents created).
    opset : int
        ONNX opset, ≥ 17.
    tile_size : int
        ``tile_size`` metadata (px, margins included; 0: whole frames).
    measure_overlap : bool
        Measure ``tile_overlap`` (:func:`measure_tile_overlap`); else the
        ``receptive_radius`` of the checkpoint is the stage's margin.
    overlap : int, optional
        Write this ``tile_overlap`` instead of measuring.
    parity_tolerance : float
        Max abs torch ↔ ONNX difference accepted.
    packed : bool
        Export a :class:`~restoration.nn.network.DOConvUNet` in its
        space-to-depth form (:class:`~restoration.nn.network.SpaceToDepthForm`:
        the same function, input and output packed by its ``scale``;
        metadata ``space_to_depth``), which the stage packs while it tiles;
        other models are exported as they are.

    Returns
    -------
    dict: ``path``, ``metadata``, ``ops`` (nodes per op type), ``convs``,
    ``parity_max_abs``, ``overlap`` (the measurement), ``seconds``.

    Raises
    ------
    InputError
        Unreadable checkpoint.
    ConfigError
        Bad ``opset`` / ``tile_size``, or metadata the stage would reject.
    ExportError
        Non-constant conv weights, or parity worse than the tolerance.
    """
    import onnx
    import torch

    from isp.io.files import atomic_path
    from modules.correction import model_info
    from restoration.nn.checkpoint import load_model

    t0 = time.perf_counter()
    if opset < MIN_OPSET:
        raise ConfigError(f"opset {opset}: the export needs opset ≥ {MIN_OPSET}")
    if tile_size < 0:
        raise ConfigError(f"tile_size {tile_size}: must be ≥ 0 (0: whole frames)")
    model, info = load_model(checkpoint)
    model = model.float().eval()
    meta = dict(info.get("metadata") or {})
    if "domain" not in meta:
        raise ConfigError(f"{checkpoint}: the checkpoint's metadata has no 'domain'; the correction stage "
                          "needs it to check the model's placement")
    cfg = getattr(model, "config", {})
    attention = meta.get("attention") or cfg.get("pool", "local")   # as training writes it: the network's pool
    if "receptive_radius" in meta:
        radius = int(meta["receptive_radius"])
    else:
        from restoration.nn.network import receptive_radius

        radius = receptive_radius(model)
    md = {
        "domain": meta["domain"],
        "placement": meta.get("placement", ""),
        "lens": meta.get("lens", "?"),
        "fov_encoding": getattr(model, "fov_encoding", meta.get("fov_encoding", "none")),
        "tile_size": str(int(tile_size)),
        "receptive_radius": str(radius),
        "input_multiple": str(int(getattr(model, "input_multiple", meta.get("input_multiple", 4)))),
        "attention": attention,
        "training_data": str(meta.get("training_data", "")),
        "precision": "fp32",
        "producer": f"isp export (variant {info.get('variant')}, step {info.get('step')}, "
                    f"torch {torch.__version__}, opset {opset})",
        "variant": str(info.get("variant")),
        "model_kwargs": info.get("model_kwargs") or {},
    }
    if "process" in meta:
        md["process"] = meta["process"]
    if _device_channels(model):
        md["device_components"] = str(_device_channels(model))
        for key in ("device_design", "device_basis"):
            if meta.get(key):
                md[key] = str(meta[key])
    if overlap is not None:
        md["tile_overlap"] = str(int(overlap))
    exported, packing = model, 1
    if packed and getattr(model, "config", {}).get("scale", 1) > 1 and hasattr(model, "run"):
        from restoration.nn.network import SpaceToDepthForm

        exported = SpaceToDepthForm(model).eval()
        packing = exported.packing
        md["space_to_depth"] = str(packing)
    proto = onnx.load_from_string(_export_bytes(exported, opset, packing))
    n_conv = check_constant_weights(proto)
    set_metadata(proto, md)
    onnx.checker.check_model(proto)
    data = proto.SerializeToString()
    sess = _session(data)
    model_info(sess, Path(out_path).name)  # the stage accepts the metadata (ConfigError otherwise)
    err = onnx_parity(model, sess)
    if not err <= parity_tolerance:
        raise ExportError(f"torch vs ONNX FP32 max abs error {err:.3g} > {parity_tolerance:g}")
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    measured = None
    if measure_overlap and overlap is None:
        with tempfile.TemporaryDirectory() as d:  # measured through the stage, on a file
            tmp = Path(d) / out.name
            tmp.write_bytes(data)
            measured = _measure_into(proto, tmp)
        data = proto.SerializeToString()
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(data)
    written = {p.key: p.value for p in proto.metadata_props}
    return {"path": str(out), "metadata": written, "ops": op_counts(proto), "convs": n_conv,
            "opset": opset, "parity_max_abs": err, "parity_tolerance": parity_tolerance,
            "overlap": measured, "seconds": round(time.perf_counter() - t0, 2)}
