"""An ONNX model's metadata and graph inputs, read from the file without
onnxruntime or the ``onnx`` package.

The correction stage checks a model when the pipeline is built (its
domain, tiling, inputs), long before it runs. onnxruntime's import and a
session's graph optimisation take 0.19 s for the packaged model, and
``import onnx`` 0.17 s; the facts the check needs sit in two places of the
file's protocol buffer, the ``ModelProto``'s ``metadata_props`` (field 14)
and its graph's ``input`` list (``GraphProto`` field 11), which this module
reads in a few milliseconds. The session is then loaded in the background
while the first stages run (:meth:`modules.correction.Correction.prepare`).

The wire format is protocol buffers' (https://protobuf.dev/programming-guides/encoding/):
each field a varint key ``number << 3 | wire type``, then a varint (type
0), 8 bytes (1), a varint length and as many bytes (2) or 4 bytes (5).
The message layouts are those of ``onnx/onnx.proto`` (IR version 3 and
later): only the fields named below are read, every other field is
skipped by its wire type.

>>> from modules.correction import resolve_model
>>> h = read_header(resolve_model("default"))
>>> h.get_modelmeta().custom_metadata_map["domain"]
'camera_rgb'
>>> [(i.name, i.type) for i in h.get_inputs()]
[('input', 'tensor(float)')]
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from isp.errors import ConfigError

#: ``TensorProto.DataType`` → onnxruntime's type string (``NodeArg.type``)
ELEMENT_TYPES = {1: "tensor(float)", 2: "tensor(uint8)", 3: "tensor(int8)", 4: "tensor(uint16)",
                 5: "tensor(int16)", 6: "tensor(int32)", 7: "tensor(int64)", 8: "tensor(string)",
                 9: "tensor(bool)", 10: "tensor(float16)", 11: "tensor(double)", 12: "tensor(uint32)",
                 13: "tensor(uint64)", 16: "tensor(bfloat16)"}

# field numbers (onnx.proto)
_MODEL_GRAPH, _MODEL_METADATA = 7, 14
_GRAPH_INITIALIZER, _GRAPH_INPUT = 5, 11
_ENTRY_KEY, _ENTRY_VALUE = 1, 2
_VALUE_NAME, _VALUE_TYPE = 1, 2
_TYPE_TENSOR = 1
_TENSOR_ELEM, _TENSOR_SHAPE = 1, 2
_SHAPE_DIM = 1
_DIM_VALUE, _DIM_PARAM = 1, 2
_INITIALIZER_NAME = 8


class _Truncated(ValueError):
    pass


def _varint(buf: memoryview, i: int) -> tuple[int, int]:
    v = shift = 0
    while True:
        if i >= len(buf):
            raise _Truncated("varint runs past the end")
        b = buf[i]
        i += 1
        v |= (b & 0x7F) << shift
        if b < 0x80:
            return v, i
        shift += 7
        if shift > 63:
            raise _Truncated("varint longer than 10 bytes")


def fields(buf: memoryview):
    """``(number, wire type, value)`` of each field of a message: ``value``
    an int for varints and fixed-size fields, a memoryview for
    length-delimited ones (strings, bytes, sub-messages)."""
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        num, wire = key >> 3, key & 7
        if wire == 0:
            v, i = _varint(buf, i)
        elif wire == 1:
            v, i = int.from_bytes(buf[i:i + 8], "little"), i + 8
        elif wire == 2:
            size, i = _varint(buf, i)
            v, i = buf[i:i + size], i + size
        elif wire == 5:
            v, i = int.from_bytes(buf[i:i + 4], "little"), i + 4
        else:
            raise _Truncated(f"wire type {wire} (groups are not used by ONNX)")
        if i > n:
            raise _Truncated("a field runs past the end")
        yield num, wire, v


def _text(v) -> str:
    return bytes(v).decode("utf-8")


@dataclass(frozen=True)
class InputArg:
    """A graph input as onnxruntime's ``NodeArg`` describes it: ``shape``
    has an int per fixed dimension, the parameter's name (or None) for the
    others."""

    name: str
    type: str
    shape: list = field(default_factory=list)


@dataclass(frozen=True)
class ModelMeta:
    custom_metadata_map: dict


@dataclass(frozen=True)
class ModelHeader:
    """What :func:`read_header` found: the methods of an onnxruntime
    ``InferenceSession`` that read a model's description, so code written
    for a session (:func:`modules.correction.model_info`) takes either."""

    metadata: dict
    inputs: tuple[InputArg, ...]

    def get_modelmeta(self) -> ModelMeta:
        return ModelMeta(dict(self.metadata))

    def get_inputs(self) -> list[InputArg]:
        return list(self.inputs)


def _input(buf) -> InputArg:
    name, elem, shape = "", 0, []
    for num, wire, v in fields(buf):
        if num == _VALUE_NAME and wire == 2:
            name = _text(v)
        elif num == _VALUE_TYPE and wire == 2:
            for tnum, twire, tv in fields(v):
                if tnum != _TYPE_TENSOR or twire != 2:
                    continue
                for k, kw, kv in fields(tv):
                    if k == _TENSOR_ELEM and kw == 0:
                        elem = kv
                    elif k == _TENSOR_SHAPE and kw == 2:
                        for d, dw, dv in fields(kv):
                            if d != _SHAPE_DIM or dw != 2:
                                continue
                            dim = None
                            for dn, dnw, dnv in fields(dv):
                                if dn == _DIM_VALUE and dnw == 0:
                                    dim = dnv
                                elif dn == _DIM_PARAM and dnw == 2:
                                    dim = _text(dnv)
                            shape.append(dim)
    return InputArg(name, ELEMENT_TYPES.get(elem, f"tensor(type {elem})"), shape)


def read_header(path: str | os.PathLike) -> ModelHeader:
    """The custom metadata and the graph inputs (initializers excluded, as
    onnxruntime lists them) of the ONNX file at ``path``. ConfigError
    naming the file when it is not an ONNX model."""
    p = Path(path)
    try:
        buf = memoryview(p.read_bytes())
    except OSError as e:
        raise ConfigError(f"{p}: cannot read ({e.strerror or e})") from None
    metadata: dict = {}
    inputs: list[InputArg] = []
    initializers: set[str] = set()
    graphs = 0
    try:
        for num, wire, v in fields(buf):
            if num == _MODEL_METADATA and wire == 2:
                entry = {k: _text(x) for k, w, x in fields(v) if w == 2 and k in (_ENTRY_KEY, _ENTRY_VALUE)}
                metadata[entry.get(_ENTRY_KEY, "")] = entry.get(_ENTRY_VALUE, "")
            elif num == _MODEL_GRAPH and wire == 2:
                graphs += 1
                for g, gw, gv in fields(v):
                    if g == _GRAPH_INPUT and gw == 2:
                        inputs.append(_input(gv))
                    elif g == _GRAPH_INITIALIZER and gw == 2:
                        initializers.update(_text(x) for k, w, x in fields(gv)
                                            if k == _INITIALIZER_NAME and w == 2)
    except (_Truncated, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: not a loadable ONNX model ({e})") from None
    if graphs != 1:
        raise ConfigError(f"{p}: not a loadable ONNX model (no graph)")
    return ModelHeader(metadata, tuple(i for i in inputs if i.name not in initializers))
