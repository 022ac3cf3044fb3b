"""Static INT8 quantisation (QDQ) of an exported correction model, and the
checks that it paid off.

:func:`quantize_int8` runs onnxruntime's ``quant_pre_process`` (ONNX shape
inference and graph clean-up; symbolic shape inference skipped, the dynamic
H, W need none), then ``quantize_static`` in QDQ form: per-channel int8
weights (7-bit range on x86, see :func:`quantize_int8`), uint8 activations
(99.99th-percentile ranges), scales fixed by a calibration pass over crops of
synthesised training inputs (:class:`SynthCalibration`); the nodes outside
the conv network (input split and encoding, field features, the output
residual and decoding) stay float (:func:`float_io_nodes`). The scales are
static, as the tiled correction stage requires (a scale computed from the
input would differ between tiles).

Why these choices (measured, ``benchmarks/doconv_speed.py``; ORT 1.31,
2 threads, x86): signed int8 activations left the residual blocks unfused
(INT8 slower than FP32); uint8 activations fused every conv into
``QLinearConv``. Only convs with constant weights can be quantised
statically (:func:`export.onnx_export.check_constant_weights`).

After quantising, :func:`count_quantized_convs` loads the model with every
graph optimisation (what the stage does) and counts, in the optimised graph
ORT writes out, the convs that became ``QLinearConv`` (or
``ConvInteger``) and those left in float; any float conv is an error.

Before quantising, the graph is rewritten into the forms ONNX Runtime's
INT8 kernels run fast (:mod:`export.int8_form`: no one-channel product
broadcast over many channels, no conv on three input channels); the FP32
twin of an INT8 file (:func:`dequantize_qdq`) is rewritten back.

:func:`mobile_usability` runs ``onnxruntime.tools.check_onnx_model_mobile_usability``
and keeps what it prints.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np

from isp.errors import ConfigError, InputError

from export.int8_form import float_form, int8_form
from export.onnx_export import ExportError, op_counts, prune_dead_nodes, set_metadata

__all__ = ["SynthCalibration", "count_quantized_convs", "dequantize_qdq", "int8_psnr", "mobile_usability", "float_io_nodes",
           "quantize_int8", "synth_crops"]

#: op types that are a quantised conv in ORT's optimised CPU graph
QUANT_CONV_OPS = ("QLinearConv", "ConvInteger", "NhwcQLinearConv")
#: op types that are a float conv there
FLOAT_CONV_OPS = ("Conv", "FusedConv", "NhwcFusedConv", "NhwcConv", "ConvTranspose")
#: INT8 vs FP32 PSNR drop accepted (dB; the export's check on held-out pairs)
PSNR_DROP_LIMIT = 0.2


def _pairs(directory):
    from restoration.train.dataset import SynthPairs

    d = Path(directory)
    if not (d / "manifest.json").is_file():
        raise InputError(d, "not a synth folder (no manifest.json); make one with `isp synth`")
    return SynthPairs(d)


def synth_crops(directory, n: int, *, crop: int = 128, multiple: int = 4, fov: bool = True,
                indices=None, seed: int = 0, device: int = 0) -> Iterator[np.ndarray]:
    """``n`` model inputs (1, C, crop, crop) float32 from a synth folder.

    Pairs are taken spread over the set (``indices`` overrides), one crop
    each at a random origin that is a multiple of ``multiple`` (the field
    channels, from :class:`restoration.train.dataset.SynthPairs`, move with
    it, and the first ``device`` descriptor channels of a set that has them).
    """
    pairs = _pairs(directory)
    if n < 1:
        raise ConfigError(f"calibration needs at least 1 crop, got {n}")
    rng = np.random.default_rng(seed)
    idx = list(indices) if indices is not None else np.linspace(0, len(pairs) - 1, n).round().astype(int)
    for i in idx[:n]:
        item = pairs[int(i)]
        x = item["input"].transpose(2, 0, 1)
        if fov:
            x = np.concatenate([x, item["fov"]])
        if device:
            x = np.concatenate([x, _descriptor_channels(item, device, directory)])
        h, w = x.shape[1:]
        c = min(crop, h, w) // multiple * multiple
        y0 = int(rng.integers(0, (h - c) // multiple + 1)) * multiple
        x0 = int(rng.integers(0, (w - c) // multiple + 1)) * multiple
        yield np.ascontiguousarray(x[None, :, y0:y0 + c, x0:x0 + c], dtype=np.float32)


def _descriptor_channels(item: dict, k: int, directory) -> np.ndarray:
    """The first ``k`` descriptor channels of a pair (ConfigError where its set has fewer)."""
    d = item.get("descriptor")
    if d is None or d.shape[0] < k:
        have = "none" if d is None else d.shape[0]
        raise ConfigError(f"{directory}: the model reads {k} device-descriptor channels; this set's pairs carry "
                          f"{have} (synthesise it with --basis)")
    return d[:k]


class SynthCalibration:
    """onnxruntime ``CalibrationDataReader`` over :func:`synth_crops`
    (``get_next`` → ``{input_name: (1, C, crop, crop)}``, None at the end)."""

    def __init__(self, directory, n: int, *, input_name: str = "input", crop: int = 128, fov: bool = True,
                 seed: int = 0, device: int = 0):
        self.directory, self.n, self.input_name = directory, n, input_name
        self.crop, self.fov, self.seed, self.device = crop, fov, seed, device
        _pairs(directory)  # fail now, not inside the calibration
        self.rewind()

    def rewind(self):
        self._it = synth_crops(self.directory, self.n, crop=self.crop, fov=self.fov, seed=self.seed,
                               device=self.device)

    def get_next(self):
        x = next(self._it, None)
        return None if x is None else {self.input_name: x}

    def __len__(self):
        return self.n


class PackedReader:
    """A calibration reader whose image inputs are packed ``s × s`` to depth
    (:func:`modules.correction.pack_input`), for a model exported so."""

    def __init__(self, reader, packing: int):
        self.reader, self.packing = reader, packing

    def rewind(self):
        self.reader.rewind()

    def get_next(self):
        from modules.correction import pack_input

        feed = self.reader.get_next()
        return None if feed is None else {k: pack_input(v, self.packing) for k, v in feed.items()}

    def __len__(self):
        return len(self.reader)


def optimized_graph(path, threads: int = 2):
    """The graph ORT runs after every optimisation (``ORT_ENABLE_ALL``, as the
    stage loads it), as an ``onnx.ModelProto``."""
    import onnx
    import onnxruntime as ort

    from modules.correction import session_options

    with tempfile.TemporaryDirectory() as d:
        opts = session_options(threads)
        opts.optimized_model_filepath = str(Path(d) / "optimized.onnx")
        ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        return onnx.load(opts.optimized_model_filepath)


def count_quantized_convs(fp32, int8_path) -> dict:
    """Convs of the float model (a path or an ``onnx.ModelProto``: the
    graph that was quantised) vs quantised and float convs in the
    optimised INT8 graph (module docstring). Keys ``fp32_conv``,
    ``int8_quantized_conv``, ``int8_float_conv``, ``int8_optimized_ops``."""
    import onnx

    fp32 = op_counts(fp32 if isinstance(fp32, onnx.ModelProto) else onnx.load(str(fp32)))
    opt = op_counts(optimized_graph(int8_path))
    return {"fp32_conv": fp32.get("Conv", 0),
            "int8_quantized_conv": sum(opt.get(k, 0) for k in QUANT_CONV_OPS),
            "int8_float_conv": sum(opt.get(k, 0) for k in FLOAT_CONV_OPS),
            "int8_optimized_ops": opt}


def float_io_nodes(model) -> list[str]:
    """Names of the nodes outside the conv network, kept in float by
    :func:`quantize_int8`: those no conv feeds (the input's split and
    encoding, the field features) and those that feed no conv (the output
    residual ``input RGB + correction``, a decoding), except a node read
    straight from a conv's output, which stays quantised so that the conv
    keeps the Q it needs to fuse into a ``QLinearConv``. So the input is
    rounded only where a conv reads it, and the output not at all."""
    consumers: dict[str, list] = {}
    for n in model.graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)
    producer = {o: n for n in model.graph.node for o in n.output}
    convs = [n for n in model.graph.node if n.op_type == "Conv"]

    def closure(step):
        seen, todo = set(), list(convs)
        while todo:
            for m in step(todo.pop()):
                if m.name not in seen:
                    seen.add(m.name)
                    todo.append(m)
        return seen

    below = closure(lambda n: [c for o in n.output for c in consumers.get(o, [])])
    above = closure(lambda n: [producer[i] for i in n.input if i in producer])

    def fed_by_conv(n):
        return any(i in producer and producer[i].op_type == "Conv" for i in n.input)

    return [n.name for n in model.graph.node if n.op_type != "Conv"
            and (n.name not in below or (n.name not in above and not fed_by_conv(n)))]


class HighPass(NamedTuple):
    """One residual high-pass of a graph (:func:`highpass_chains`)."""

    residual: str  #: the tensor ``r`` it filters
    chain: list  #: the tensors from ``r`` to ``box(r)`` (Pad and Conv outputs, ``box(r)`` included)
    sub: str  #: the name of the node ``Sub(r, box(r))`` (kept by the quantiser)


def highpass_chains(model) -> list[HighPass]:
    """The residual high-passes of a graph (:class:`restoration.nn.network.ResidualHighPass`):
    each ``Sub(r, m)`` whose ``m`` comes from ``r`` through ``Pad`` and
    ``Conv`` nodes only."""
    producer = {o: n for n in model.graph.node for o in n.output}
    out = []
    for sub in (n for n in model.graph.node if n.op_type == "Sub"):
        r, t, chain = sub.input[0], sub.input[1], []
        while t in producer and producer[t].op_type in ("Conv", "Pad") and t != r:
            chain.append(t)
            t = producer[t].input[0]
        if chain and t == r and any(producer[c].op_type == "Conv" for c in chain):
            out.append(HighPass(r, chain, sub.name))
    return out


class ReplayReader:
    """A calibration reader that yields the feeds of another, read once, as
    often as it is rewound (any ``CalibrationDataReader`` can be read
    twice through it)."""

    def __init__(self, reader):
        self.feeds = list(iter(reader.get_next, None))
        self.rewind()

    def rewind(self):
        self._it = iter(self.feeds)

    def get_next(self):
        return next(self._it, None)

    def __len__(self):
        return len(self.feeds)


def shared_range_overrides(model_path, chains, calibration_reader, method, percentile: float) -> dict:
    """``TensorQuantOverrides`` that give every tensor of each residual
    high-pass in ``chains`` (:func:`highpass_chains` of the model at
    ``model_path``) the calibrated range of the residual it filters.

    Calibrated on their own, the box means get the narrow range that natural
    images give them (a residual's local mean is near 0 there) and clip
    where a frame is far from the calibration crops: on a flat grey field at
    0.7 an e9 model with a 9-pixel box came out 8.7 % too
    bright in INT8 (0.1 % in FP32). With the residual's own range the
    subtraction ``r − box(r)`` cannot clip beyond ``r`` itself. One extra
    calibration pass over the same crops: ``calibration_reader`` is rewound
    after it (a :class:`ReplayReader`, or one with ``rewind``)."""
    from onnxruntime.quantization.calibrate import create_calibrator

    if not chains:
        return {}
    with tempfile.TemporaryDirectory() as d:
        cal = create_calibrator(str(model_path), None, augmented_model_path=str(Path(d) / "aug.onnx"),
                                calibrate_method=method,
                                extra_options={"percentile": percentile} if percentile is not None else {})
        cal.collect_data(calibration_reader)
        ranges = cal.compute_data()
    calibration_reader.rewind()
    overrides = {}
    for r, chain, _ in chains:
        lo, hi = (float(v) for v in ranges[r].range_value)
        for t in chain:
            overrides[t] = [{"rmin": np.float32(lo), "rmax": np.float32(hi)}]
    return overrides


def highpass_reads_float(model, chains) -> int:
    """Let the ``Sub(r, box(r))`` of each residual high-pass in ``chains``
    (:func:`highpass_chains`) read ``r`` unrounded where a float node made
    it (the linear residual ``r (r + 2u)``, an element-wise ``Mul``), not a
    conv, whose output must stay quantised for it to fuse into a
    ``QLinearConv``; returns how many.

    Through the rounded ``r`` its quantisation step reaches the output
    whole, uniform in linear RGB, where the sRGB gamma magnifies it in the
    shadows; the box mean averages it over 81 pixels. Measured on the e9
    default with the linear high-pass (48 held-out pairs): INT8
    drop 0.186 dB with the rounded ``r``, 0.138 dB with this, every conv
    still quantised."""
    prod = {o: n for n in model.graph.node for o in n.output}
    float_made = {hp.sub: hp.residual for hp in chains
                  if hp.residual in prod and prod[hp.residual].op_type not in ("Conv", "QuantizeLinear")}
    count = 0
    for sub in (n for n in model.graph.node if n.name in float_made):
        sub.input[0] = float_made[sub.name]
        count += 1
    if count:
        prune_dead_nodes(model)
    return count


def bypass_input_qdq(model, nodes: list[str]) -> int:
    """Feed the float ``nodes`` their inputs unrounded: where an input is
    ``DequantizeLinear(QuantizeLinear(t))`` (a pair the quantiser put there
    for *another* consumer of ``t``, e.g. the stem conv reading the same
    RGB the output residual passes through), read ``t`` itself. Returns the
    inputs rewired. Without it the float residual ``Add`` still passed the
    input RGB through uint8 steps: 2.1 dB of PSNR lost on the e9 model."""
    prod = {o: n for n in model.graph.node for o in n.output}
    inits = {i.name for i in model.graph.initializer}
    count = 0
    for node in model.graph.node:
        if node.name not in nodes:
            continue
        for k, name in enumerate(node.input):
            dq = prod.get(name)
            if dq is None or dq.op_type != "DequantizeLinear":
                continue
            q = prod.get(dq.input[0])
            if q is None or q.op_type != "QuantizeLinear" or q.input[0] in inits:
                continue
            node.input[k] = q.input[0]
            count += 1
    return count


def quantized_pads(model) -> int:
    """Run each ``DequantizeLinear → Pad → QuantizeLinear`` whose two sides
    share one scale and zero point on the uint8 tensor itself, the pair
    removed; returns how many. An edge or reflect ``Pad`` copies values, so
    this is exact; ONNX Runtime keeps such a Pad in float otherwise, with a
    DequantizeLinear before and a QuantizeLinear after it (for the residual
    high-pass, whose ranges :func:`shared_range_overrides` makes equal). A
    constant Pad (whose 0 is not the zero point) is left alone."""
    from onnx import helper, numpy_helper

    g = model.graph
    consts = {i.name: numpy_helper.to_array(i) for i in g.initializer}
    prod = {o: n for n in g.node for o in n.output}
    readers: dict[str, list] = {}
    for n in g.node:
        for i in n.input:
            readers.setdefault(i, []).append(n)

    def same(a, b):
        return a in consts and b in consts and np.array_equal(consts[a], consts[b])

    count = 0
    for pad in [n for n in g.node if n.op_type == "Pad"]:
        mode = next((helper.get_attribute_value(a) for a in pad.attribute if a.name == "mode"), b"constant")
        dq = prod.get(pad.input[0])
        users = readers.get(pad.output[0], [])
        if (mode in (b"constant", "constant") or dq is None or dq.op_type != "DequantizeLinear"
                or len(users) != 1 or users[0].op_type != "QuantizeLinear"):
            continue
        q = users[0]
        if not (same(dq.input[1], q.input[1]) and same(dq.input[2], q.input[2])):
            continue
        pad.input[0] = dq.input[0]
        for n in readers.get(q.output[0], []):
            for j, name in enumerate(n.input):
                if name == q.output[0]:
                    n.input[j] = pad.output[0]
        for vi in [v for v in g.value_info if v.name == pad.output[0]]:   # it is uint8 now
            g.value_info.remove(vi)
        count += 1
    if count:
        prune_dead_nodes(model)
    return count


def dequantize_qdq(model):
    """The FP32 twin of a QDQ model: every ``DequantizeLinear`` of a constant
    (weights, biases) folded into a float initializer, every activation
    ``QuantizeLinear`` → ``DequantizeLinear`` pair removed. The twin computes
    the FP32 graph with the INT8 model's rounded weights, so it is the peer a
    speed comparison needs when only the shipped INT8 file is at hand
    (``benchmarks/correction.py``); its outputs differ from the INT8 model's
    by the activation rounding only. Modifies and returns ``model``
    (``onnx.ModelProto``); metadata ``precision`` becomes ``fp32-dequantized``.

    Example
    -------
    >>> from pathlib import Path
    >>> import onnx
    >>> import modules
    >>> shipped = Path(modules.__file__).parent / "models" / "e9_default.int8.onnx"
    >>> fp32 = dequantize_qdq(onnx.load(shipped))
    >>> {p.key: p.value for p in fp32.metadata_props}["precision"]
    'fp32-dequantized'
    """
    from onnx import helper, numpy_helper

    g = model.graph
    consts = {i.name: i for i in g.initializer}
    prod = {o: n for n in g.node for o in n.output}
    alias, folded, drop = {}, [], set()
    for k, n in enumerate(g.node):
        if n.op_type != "DequantizeLinear":
            continue
        if n.input[0] in consts:
            q = numpy_helper.to_array(consts[n.input[0]]).astype(np.float64)
            scale = numpy_helper.to_array(consts[n.input[1]]).astype(np.float64)
            zero = (numpy_helper.to_array(consts[n.input[2]]).astype(np.float64)
                    if len(n.input) > 2 and n.input[2] else np.zeros_like(scale))
            if scale.ndim == 1 and q.ndim > 1:   # per-channel along ``axis``
                axis = next((helper.get_attribute_value(a) for a in n.attribute if a.name == "axis"), 1)
                shape = [1] * q.ndim
                shape[axis] = -1
                scale, zero = scale.reshape(shape), zero.reshape(shape)
            folded.append(numpy_helper.from_array(((q - zero) * scale).astype(np.float32), n.output[0]))
            drop.add(k)
        else:
            q = prod.get(n.input[0])
            if q is not None and q.op_type == "QuantizeLinear":
                alias[n.output[0]] = q.input[0]
                drop.add(k)
            elif q is not None and q.op_type == "Pad" and prod.get(q.input[0]) is not None \
                    and prod[q.input[0]].op_type == "QuantizeLinear":   # a quantized_pads Pad: back to float
                q.input[0] = prod[q.input[0]].input[0]
                alias[n.output[0]] = q.output[0]
                drop.add(k)

    def resolve(name):
        while name in alias:
            name = alias[name]
        return name

    kept = [n for k, n in enumerate(g.node) if k not in drop]
    for n in kept:
        for j, name in enumerate(n.input):
            n.input[j] = resolve(name)
    for o in g.output:
        o.name = resolve(o.name)
    # the QuantizeLinear nodes nobody reads any more, then the unused constants
    used = {i for n in kept for i in n.input} | {o.name for o in g.output}
    kept = [n for n in kept if n.op_type != "QuantizeLinear" or any(o in used for o in n.output)]
    used = {i for n in kept for i in n.input} | {o.name for o in g.output}
    inits = [i for i in g.initializer if i.name in used] + [i for i in folded if i.name in used]
    del g.node[:]
    g.node.extend(kept)
    del g.initializer[:]
    g.initializer.extend(inits)
    del g.value_info[:]   # the quantiser's shapes name tensors that are gone
    float_form(model)     # the INT8 file's graph forms (export.int8_form) back to float's own
    set_metadata(model, {"precision": "fp32-dequantized"})
    return model


#: activation range calibration: the 99.9th percentile of each tensor's
#: |values| over the calibration crops (ORT's "Percentile"); see quantize_int8
CALIBRATION = "percentile"
PERCENTILE = 99.9


def quantize_int8(fp32_path, out_path, calibration_reader, *, per_channel: bool = True,
                  float_output_add: bool = True, require_all_quantized: bool = True,
                  reduce_range: bool = True, calibration: str = CALIBRATION,
                  percentile: float = PERCENTILE, graph_forms: bool = True) -> dict:
    """Static INT8 (QDQ) copy of an exported FP32 model.

    Parameters
    ----------
    fp32_path : path
        Written by :func:`export.onnx_export.export_onnx`.
    out_path : path
        The INT8 model (written atomically); its metadata is the FP32
        model's with ``precision = "int8"`` and the calibration noted.
    calibration_reader : onnxruntime.quantization.CalibrationDataReader
        E.g. :class:`SynthCalibration`.
    per_channel : bool
        Per-output-channel weight scales.
    float_output_add : bool
        Keep the nodes outside the conv network in float
        (:func:`float_io_nodes`: the output residual ``Add``, input
        RGB + correction, and any input encoding or output decoding), reading
        their inputs unrounded (:func:`bypass_input_qdq`). With
        ``encoding="sqrt"`` (1,500 steps) the drop is then 0.04 dB, against
        0.13 dB for the linear model of the same budget. Quantised, the Add rounds the
        *passed-through* input and the output to uint8 steps of ≈ 1/200 of
        the linear range, which the sRGB gamma amplifies in the shadows:
        measured on the e9 model (step 150), 16 synth pairs, PSNR drop
        0.41 dB with it quantised, 0.05 dB in float; every conv stays INT8.
    require_all_quantized : bool
        Raise ExportError if a conv stays float after optimisation.
    reduce_range : bool
        7-bit weights. On x86 without VNNI (AVX2) ONNX Runtime multiplies
        uint8 × int8 with ``vpmaddubsw``, which saturates the int16 sum of
        two products; per-channel scales put every channel's largest weight
        at ±127 and saturate often. Measured on the default e9 model (16
        held-out synth pairs): PSNR drop 2.03 dB with 8-bit weights, 0.37 dB
        with 7 (min-max ranges); uint8 weights (no saturation) 0.36 dB.
    graph_forms : bool
        Quantise the graph in the forms INT8 runs fast
        (:func:`export.int8_form.int8_form`); off only to measure what they
        buy (``benchmarks/int8_form.py``).
    calibration, percentile : {"percentile", "minmax"}, float
        Activation ranges: the ``percentile`` of each tensor's values, or
        its extremes. Measured as above, with 7-bit weights, 16 pairs:
        min-max 0.37 dB, percentiles 99.999: 0.34, 99.99: 0.29, 99.9: 0.21,
        99.5: 0.17 dB; entropy (ORT's "Entropy") 2.0 dB. On 48 pairs the
        percentiles are closer: 99.9: 0.24, 99.5: 0.25, 99.0: 0.27 dB.

    Returns
    -------
    dict: ``path``, the counts of :func:`count_quantized_convs`, ``ops``
    (QDQ graph), ``seconds``.
    """
    import onnx
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from isp.io.files import atomic_path

    t0 = time.perf_counter()
    src = onnx.load(str(fp32_path))
    meta = {p.key: p.value for p in src.metadata_props}
    packing = int(meta.get("space_to_depth", 1))
    if packing > 1:   # the reader yields the model's unpacked inputs, as the stage sees frames
        calibration_reader = PackedReader(calibration_reader, packing)
    with tempfile.TemporaryDirectory() as d:
        pre, q = Path(d) / "pre.onnx", Path(d) / "q.onnx"
        quant_pre_process(str(fp32_path), str(pre), skip_symbolic_shape=True)
        pre_model = onnx.load(str(pre))
        # the shapes INT8 kernels run fast (export.int8_form); dequantize_qdq undoes them
        rewritten = int8_form(pre_model) if graph_forms else {}
        onnx.save(pre_model, str(pre))
        exclude = float_io_nodes(pre_model) if float_output_add else []
        method = CalibrationMethod.Percentile if calibration == "percentile" else CalibrationMethod.MinMax
        chains = highpass_chains(pre_model)
        overrides = {}
        if chains:   # two calibration passes: read the crops once
            calibration_reader = ReplayReader(calibration_reader)
            overrides = shared_range_overrides(pre, chains, calibration_reader, method,
                                               percentile if calibration == "percentile" else None)
        quantize_static(str(pre), str(q), calibration_reader, quant_format=QuantFormat.QDQ,
                        per_channel=per_channel, activation_type=QuantType.QUInt8,
                        weight_type=QuantType.QInt8, nodes_to_exclude=exclude, reduce_range=reduce_range,
                        calibrate_method=method,
                        # Relu stays in the file (ORT fuses it into the Q before it at load time: the
                        # same kernels); dropped, the Q's zero point alone clamps at 0, and the FP32
                        # twin (dequantize_qdq) lost every Relu of the network
                        extra_options={"QDQKeepRemovableActivations": True,
                                       **({"TensorQuantOverrides": overrides} if overrides else {}),
                                       **({"CalibPercentile": percentile} if calibration == "percentile" else {})})
        model = onnx.load(str(q))
    if exclude:
        bypass_input_qdq(model, exclude)
        prune_dead_nodes(model)
    if overrides:
        quantized_pads(model)
    highpass_reads_float(model, chains)
    n = len(calibration_reader) if hasattr(calibration_reader, "__len__") else None
    set_metadata(model, {**meta, "precision": "int8",
                         "quantization": f"static QDQ, int8 weights ({'per channel' if per_channel else 'per tensor'}"
                                         f"{', 7-bit range' if reduce_range else ''}), uint8 activations "
                                         f"({calibration}{f' {percentile}' if calibration == 'percentile' else ''}), "
                                         f"{n if n is not None else '?'} calibration crops",
                         "producer": meta.get("producer", "isp export") + "; onnxruntime.quantization"})
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        onnx.save(model, str(tmp))
    counts = count_quantized_convs(pre_model, out)
    if require_all_quantized and (counts["int8_float_conv"] or counts["int8_quantized_conv"] < counts["fp32_conv"]):
        raise ExportError(f"{out}: after optimisation {counts['int8_quantized_conv']} of {counts['fp32_conv']} "
                          f"convs are quantised and {counts['int8_float_conv']} stay float")
    return {"path": str(out), **counts, "float_nodes": exclude, "int8_form": rewritten, "ops": op_counts(model),
            "seconds": round(time.perf_counter() - t0, 2)}


def mobile_usability(path, timeout: float = 300) -> dict:
    """Run onnxruntime's mobile-usability checker on a model; ``returncode``
    and ``output`` (what it logs, stdout and stderr)."""
    cmd = [sys.executable, "-m", "onnxruntime.tools.check_onnx_model_mobile_usability", str(path)]
    r = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=timeout)
    return {"returncode": r.returncode, "output": (r.stdout + r.stderr).strip()}


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def int8_psnr(fp32_path, int8_path, directory, n: int = 16, *, indices=None, threads: int = 2) -> dict:
    """PSNR (dB, sRGB, peak 1) of ``Process(Model(J))`` against the targets
    for the FP32 and the INT8 model, on ``n`` pairs of a synth folder
    (default: the last ``n``, away from the calibration crops that
    :func:`synth_crops` spreads over the set), whole pairs in one call each.

    Returns
    -------
    dict: ``fp32_psnr_db``, ``int8_psnr_db``, ``input_psnr_db`` (no
    correction), ``drop_db`` (FP32 − INT8), ``pairs``.
    """
    import onnxruntime as ort

    from modules.correction import model_info, run_model, session_options

    pairs = _pairs(directory)
    idx = list(indices) if indices is not None else list(range(max(0, len(pairs) - n), len(pairs)))
    sess = [ort.InferenceSession(str(p), session_options(threads), providers=["CPUExecutionProvider"])
            for p in (fp32_path, int8_path)]
    infos = [model_info(s) for s in sess]
    fov = infos[0].fov_encoding == "xy"
    scores = {"input": [], "fp32": [], "int8": []}
    for i in idx:
        item = pairs[int(i)]
        rgb = item["input"]
        h, w = (s // 4 * 4 for s in rgb.shape[:2])
        x = rgb.transpose(2, 0, 1)[:, :h, :w]
        if fov:
            x = np.concatenate([x, item["fov"][:, :h, :w]])
        if infos[0].device:
            x = np.concatenate([x, _descriptor_channels(item, infos[0].device, directory)[:, :h, :w]])
        x = np.ascontiguousarray(x[None], dtype=np.float32)
        target = item["target"][:h, :w]
        scores["input"].append(_psnr(pairs.process(rgb[:h, :w], item), target))
        for key, s, info in zip(("fp32", "int8"), sess, infos):
            y = run_model(s, x, info)[0].transpose(1, 2, 0)
            scores[key].append(_psnr(pairs.process(y, item), target))
    mean = {k: float(np.mean(v)) for k, v in scores.items()}
    return {"pairs": len(idx), "input_psnr_db": mean["input"], "fp32_psnr_db": mean["fp32"],
            "int8_psnr_db": mean["int8"], "drop_db": mean["fp32"] - mean["int8"], "limit_db": PSNR_DROP_LIMIT}
