"""Graph forms that ONNX Runtime's x86 INT8 kernels run faster, and their
float inverses.

The exported FP32 graph is the form float runs fastest; static INT8 runs
in a different world (channels-last uint8 tensors, ``QLinear*`` kernels
whose speed depends on the tensor shapes more than on the arithmetic). Two
shapes were measured to cost INT8 far more than the work they do
(ONNX Runtime 1.32, two threads of an AMD EPYC with AVX-512 VNNI):

* **A one-channel map broadcast over many channels.** DOConv's kernel
  attention ``α_w,i`` is one map per kernel, multiplied into that
  kernel's 48-channel output. INT8's ``QLinearMul`` broadcasts it pixel by
  pixel (a 48-value span times a scalar); float broadcasts it plane by
  plane and is fast. :func:`spread_broadcast_muls` replaces the
  one-channel slice by a 1×1 conv of one-hot constant weights that copies
  that kernel's attention to every channel (the same values), so the
  product is element by element.
* **Three input channels.** The field features ``(x, y, x² + y²)`` enter
  1×1 convs, which ONNX Runtime's INT8 kernel runs at half the speed it
  runs four. :func:`pad_thin_convs` appends a copy of the concatenation's
  last input and gives the convs zero weights for it: the same function.

On the packaged e9 model the twelve products took 10.4–10.6 ms broadcast
and 5.2 ms spread, the four field convs 2.8–3.5 ms and 1.3 ms, and a
1,072² INT8 window 6.6–6.9 % less; float runs the same forms 5–7 % slower
(``python -m benchmarks.int8_form``, which measures all of it).

:func:`export.quantize.quantize_int8` applies both to the FP32 graph
before quantising it (``int8_form``); :func:`float_form` undoes them, for
the FP32 twin that :func:`export.quantize.dequantize_qdq` builds from an
INT8 file, so the speed comparison gives float its own best graph.
"""

from __future__ import annotations

import numpy as np

from export.onnx_export import prune_dead_nodes

__all__ = ["float_form", "int8_form", "pad_thin_convs", "spread_broadcast_muls", "unpad_thin_convs",
           "unspread_broadcast_muls"]

#: input channels of a conv are padded to a multiple of this (:func:`pad_thin_convs`)
CHANNEL_MULTIPLE = 4


def _constants(model) -> dict:
    """Every constant tensor of the graph by name: initializers and
    ``Constant`` node outputs, as numpy arrays."""
    from onnx import helper, numpy_helper

    out = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    for n in model.graph.node:
        if n.op_type == "Constant":
            for a in n.attribute:
                if a.name == "value":
                    out[n.output[0]] = numpy_helper.to_array(helper.get_attribute_value(a))
    return out


def _channels(model) -> dict[str, int]:
    """The channel count (dim 1) of every tensor whose shape inference knows it."""
    import onnx

    inferred = onnx.shape_inference.infer_shapes(model)
    out = {}
    for v in list(inferred.graph.value_info) + list(inferred.graph.input) + list(inferred.graph.output):
        dims = v.type.tensor_type.shape.dim
        if len(dims) >= 2 and dims[1].HasField("dim_value"):
            out[v.name] = dims[1].dim_value
    return out


def _consumers(model) -> dict[str, list]:
    out: dict[str, list] = {}
    for n in model.graph.node:
        for i in n.input:
            out.setdefault(i, []).append(n)
    return out


def _fresh(model, base: str) -> str:
    """``base``, or ``base`` with a number appended, such that no node,
    tensor or initializer of the graph starts with that name."""
    g = model.graph
    taken = ({n.name for n in g.node} | {t for n in g.node for t in (*n.input, *n.output)}
             | {i.name for i in g.initializer})
    k, name = 0, base
    while any(t == name or t.startswith(name + ".") or t.startswith(name + "_") for t in taken):
        k += 1
        name = f"{base}{k}"
    return name


def _channel_slice(node, consts) -> int | None:
    """``i`` when ``node`` is ``Slice(x, [i], [i + 1], axes=[1] [, steps=[1]])``, else None."""
    if node.op_type != "Slice" or len(node.input) < 4:
        return None
    try:
        starts, ends, axes = (consts[k].ravel().tolist() for k in node.input[1:4])
        steps = consts[node.input[4]].ravel().tolist() if len(node.input) > 4 and node.input[4] else [1]
    except KeyError:
        return None
    if axes == [1] and steps == [1] and len(starts) == 1 and ends == [starts[0] + 1] and starts[0] >= 0:
        return int(starts[0])
    return None


def spread_broadcast_muls(model) -> int:
    """Replace each ``Mul(y, Slice(k, i:i+1 on channels))`` whose ``y`` has
    more channels than one by ``Mul(y, Conv(k, e_i))``: a 1×1 conv of
    constant one-hot weights that writes channel ``i`` of ``k`` into every
    channel of ``y`` (module docstring). Exact in float. Modifies
    ``model`` (``onnx.ModelProto``); returns the number of products
    rewritten.

    Examples
    --------
    The float twin of the shipped INT8 model has the exported graph's
    products:

    >>> from pathlib import Path
    >>> import onnx
    >>> import modules
    >>> from export.quantize import dequantize_qdq
    >>> shipped = Path(modules.__file__).parent / "models" / "e9_default.int8.onnx"
    >>> spread_broadcast_muls(dequantize_qdq(onnx.load(shipped)))
    12
    """
    from onnx import helper, numpy_helper

    g = model.graph
    consts, ch = _constants(model), _channels(model)
    produced = {o: n for n in g.node for o in n.output}
    done = 0
    for mul in [n for n in g.node if n.op_type == "Mul"]:
        for side in (0, 1):
            s, y = mul.input[side], mul.input[1 - side]
            sl = produced.get(s)
            i = None if sl is None else _channel_slice(sl, consts)
            if i is None or ch.get(y, 1) <= 1 or sl.input[0] not in ch:
                continue
            c, n = ch[y], ch[sl.input[0]]
            w = np.zeros((c, n, 1, 1), np.float32)
            w[:, i] = 1.0
            # a graph spread before and spread back (an INT8 file's twin) holds these names already
            name = _fresh(model, f"{mul.name}/spread")
            g.initializer.append(numpy_helper.from_array(w, f"{name}.weight"))
            conv = helper.make_node("Conv", [sl.input[0], f"{name}.weight"], [f"{name}_output"],
                                    name=name, kernel_shape=[1, 1])
            g.node.insert(list(g.node).index(mul), conv)   # before its reader: the order stays topological
            mul.input[side] = f"{name}_output"
            done += 1
            break
    if done:
        _drop_unused(model)
    return done


def unspread_broadcast_muls(model) -> int:
    """The inverse of :func:`spread_broadcast_muls`: every 1×1 ``Conv``
    without bias whose weights copy one input channel to all its outputs
    (one-hot rows, all alike, within 1e-5: a dequantised copy rounds them)
    and whose output only ``Mul`` nodes read becomes the one-channel
    ``Slice`` it was. Returns the number of convs removed."""
    from onnx import helper, numpy_helper

    g = model.graph
    consts, readers = _constants(model), _consumers(model)
    done = 0
    for conv in [n for n in g.node if n.op_type == "Conv"]:
        if len(conv.input) > 2 and conv.input[2] or conv.input[1] not in consts:
            continue
        w = np.asarray(consts[conv.input[1]], np.float64)
        if w.ndim != 4 or w.shape[2:] != (1, 1) or w.shape[0] < 2:
            continue
        i = int(np.argmax(np.abs(w[0, :, 0, 0])))
        onehot = np.zeros(w.shape[1])
        onehot[i] = 1.0
        if not np.allclose(w[:, :, 0, 0], onehot, atol=1e-5) or not all(
                r.op_type == "Mul" for r in readers.get(conv.output[0], [])):
            continue
        name = conv.name or conv.output[0]
        for k, v in (("starts", i), ("ends", i + 1), ("axes", 1)):
            g.initializer.append(numpy_helper.from_array(np.array([v], np.int64), f"{name}/slice_{k}"))
        sl = helper.make_node("Slice", [conv.input[0], f"{name}/slice_starts", f"{name}/slice_ends",
                                        f"{name}/slice_axes"], [conv.output[0]], name=f"{name}/slice")
        g.node[list(g.node).index(conv)].CopyFrom(sl)   # in the conv's place
        done += 1
    if done:
        _drop_unused(model)
    return done


def pad_thin_convs(model, multiple: int = CHANNEL_MULTIPLE) -> int:
    """Pad the input channels of convs fed by a ``Concat`` to a multiple of
    ``multiple``: the concatenation gets its last input again (as often as
    needed) and every conv reading it zero weights for the copies (module
    docstring). Only where every reader of the ``Concat`` is an ungrouped
    conv with constant weights. Exact. Returns the number of convs padded."""
    from onnx import helper, numpy_helper

    g = model.graph
    readers, ch = _consumers(model), _channels(model)
    inits = {i.name: i for i in g.initializer}
    done = 0
    for cat in [n for n in g.node if n.op_type == "Concat"]:
        axis = next((helper.get_attribute_value(a) for a in cat.attribute if a.name == "axis"), None)
        convs = readers.get(cat.output[0], [])
        c = ch.get(cat.output[0])
        if axis != 1 or not convs or c is None or c % multiple == 0 or not all(
                r.op_type == "Conv" and r.input[1] in inits and r.input[0] == cat.output[0]
                and all(a.name != "group" or helper.get_attribute_value(a) == 1 for a in r.attribute)
                for r in convs):
            continue
        last = cat.input[-1]
        extra = ch.get(last)
        # copies of the last input that bring the channels to a multiple (none may: skip then)
        copies = next((k for k in range(1, multiple + 1) if extra and (c + k * extra) % multiple == 0), None)
        if copies is None:
            continue
        add = copies * extra
        cat.input.extend([last] * copies)
        _forget_shape(model, cat.output[0])
        for r in convs:
            w = numpy_helper.to_array(inits[r.input[1]])
            pad = np.zeros((w.shape[0], add, *w.shape[2:]), w.dtype)
            inits[r.input[1]].CopyFrom(numpy_helper.from_array(np.concatenate([w, pad], axis=1), r.input[1]))
            done += 1
    return done


def unpad_thin_convs(model) -> int:
    """The inverse of :func:`pad_thin_convs`: a ``Concat`` whose trailing
    inputs repeat its last one, read only by convs whose weights for those
    channels are zero, loses them (and the weights their columns). Returns
    the number of convs unpadded."""
    from onnx import numpy_helper

    g = model.graph
    readers, ch = _consumers(model), _channels(model)
    inits = {i.name: i for i in g.initializer}
    done = 0
    for cat in [n for n in g.node if n.op_type == "Concat"]:
        convs = readers.get(cat.output[0], [])
        ins = list(cat.input)
        k = len(ins)
        while k > 1 and ins[k - 1] == ins[k - 2]:
            k -= 1
        extra = ch.get(ins[-1])
        if k == len(ins) or extra is None or not convs or not all(
                r.op_type == "Conv" and r.input[1] in inits for r in convs):
            continue
        drop = (len(ins) - k) * extra
        ws = [numpy_helper.to_array(inits[r.input[1]]) for r in convs]
        if not all(w.shape[1] > drop and not np.any(w[:, -drop:]) for w in ws):
            continue
        del cat.input[k:]
        _forget_shape(model, cat.output[0])
        for r, w in zip(convs, ws):
            inits[r.input[1]].CopyFrom(numpy_helper.from_array(np.ascontiguousarray(w[:, :-drop]), r.input[1]))
            done += 1
    return done


def _forget_shape(model, name: str) -> None:
    """Drop the inferred shape of tensor ``name`` (it changed)."""
    keep = [v for v in model.graph.value_info if v.name != name]
    del model.graph.value_info[:]
    model.graph.value_info.extend(keep)


def _drop_unused(model) -> None:
    """Remove the nodes nobody reads (:func:`prune_dead_nodes`), then the
    initializers nobody reads."""
    g = model.graph
    prune_dead_nodes(model)
    used = {i for n in g.node for i in n.input}
    keep = [i for i in g.initializer if i.name in used]
    del g.initializer[:]
    g.initializer.extend(keep)


def int8_form(model) -> dict:
    """:func:`spread_broadcast_muls` and :func:`pad_thin_convs` on an FP32
    graph about to be quantised; returns what each rewrote."""
    return {"spread_muls": spread_broadcast_muls(model), "padded_convs": pad_thin_convs(model)}


def float_form(model) -> dict:
    """:func:`unspread_broadcast_muls` and :func:`unpad_thin_convs`: an INT8
    form back in the form float runs fastest; returns what each undid."""
    return {"unspread_muls": unspread_broadcast_muls(model), "unpadded_convs": unpad_thin_convs(model)}
