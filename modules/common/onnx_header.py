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


def _messages(buf, number: int):
    """The length-delimited fields ``number`` of a message (sub-messages, strings)."""
    return (v for num, wire, v in fields(buf) if num == number and wire == 2)


def _varint_field(buf, number: int, default: int = 0) -> int:
    """The last varint field ``number`` of a message (protobuf's rule for a repeated scalar)."""
    out = default
    for num, wire, v in fields(buf):
        if num == number and wire == 0:
            out = v
    return out


def _dim(buf):
    """A ``TensorShapeProto.Dimension``: its value, its parameter's name, or None."""
    dim = None
    for num, wire, v in fields(buf):
        if num == _DIM_VALUE and wire == 0:
            dim = v
        elif num == _DIM_PARAM and wire == 2:
            dim = _text(v)
    return dim


def _input(buf) -> InputArg:
    """A ``ValueInfoProto``: name, tensor element type and shape."""
    name = next((_text(v) for v in _messages(buf, _VALUE_NAME)), "")
    elem, shape = 0, []
    for tensor in (t for typ in _messages(buf, _VALUE_TYPE) for t in _messages(typ, _TYPE_TENSOR)):
        elem = _varint_field(tensor, _TENSOR_ELEM, elem)
        for dims in _messages(tensor, _TENSOR_SHAPE):
            shape += [_dim(d) for d in _messages(dims, _SHAPE_DIM)]
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
                key = next((_text(x) for x in _messages(v, _ENTRY_KEY)), "")
                metadata[key] = next((_text(x) for x in _messages(v, _ENTRY_VALUE)), "")
            elif num == _MODEL_GRAPH and wire == 2:
                graphs += 1
                inputs += [_input(i) for i in _messages(v, _GRAPH_INPUT)]
                initializers.update(_text(n) for t in _messages(v, _GRAPH_INITIALIZER)
                                    for n in _messages(t, _INITIALIZER_NAME))
    except (_Truncated, UnicodeDecodeError) as e:
        raise ConfigError(f"{p}: not a loadable ONNX model ({e})") from None
    if graphs != 1:
        raise ConfigError(f"{p}: not a loadable ONNX model (no graph)")
    return ModelHeader(metadata, tuple(i for i in inputs if i.name not in initializers))
