"""The convolutions of an ONNX model, in graph order, read straight from its protobuf bytes.

Only what rebuilding a trainable model needs: each Conv node's weight, bias and attributes.
ONNX files are protobuf messages (onnx.proto: ModelProto.graph = 7, GraphProto.node = 1 and
.initializer = 5, NodeProto.input = 1 / op_type = 4 / attribute = 5, TensorProto.dims = 1,
data_type = 2, float_data = 4, name = 8, raw_data = 9); the wire format is a few lines to
walk, so the `onnx` package is not needed. ONNX lists nodes in topological order, which for
an exported network is the order its forward pass ran them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blendgen.errors import UserError

_FLOAT = 1  # TensorProto.DataType FLOAT


@dataclass
class ConvNode:
    name: str
    weight: np.ndarray            # (out, in / groups, kh, kw)
    bias: np.ndarray | None
    attrs: dict = field(default_factory=dict)  # strides, pads, group, kernel_shape, dilations


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, i
        shift += 7


def _fields(buf: bytes):
    """(field number, wire type, value) of one message: value is an int (varint, fixed) or bytes."""
    i, n = 0, len(buf)
    while i < n:
        key, i = _varint(buf, i)
        num, wt = key >> 3, key & 7
        if wt == 0:
            v, i = _varint(buf, i)
        elif wt == 1:
            v, i = buf[i:i + 8], i + 8
        elif wt == 2:
            ln, i = _varint(buf, i)
            v, i = buf[i:i + ln], i + ln
        elif wt == 5:
            v, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wt}")
        yield num, wt, v


def _tensor(buf: bytes) -> tuple[str, np.ndarray]:
    dims, dtype, name, raw, floats = [], None, "", None, []
    for num, wt, v in _fields(buf):
        if num == 1:
            if wt == 2:  # packed
                j = 0
                while j < len(v):
                    d, j = _varint(v, j)
                    dims.append(d)
            else:
                dims.append(v)
        elif num == 2:
            dtype = v
        elif num == 4:
            floats.append(np.frombuffer(v, "<f4"))  # packed (bytes) or one fixed32 value
        elif num == 8:
            name = v.decode()
        elif num == 9:
            raw = v
    if dtype != _FLOAT:
        return name, np.zeros(0)
    data = np.frombuffer(raw, "<f4") if raw is not None else (np.concatenate(floats) if floats else np.zeros(0, "<f4"))
    return name, data.astype(np.float32).reshape(dims)


def _attribute(buf: bytes):
    name, ints, i_val = "", [], None
    for num, wt, v in _fields(buf):
        if num == 1:
            name = v.decode()
        elif num == 3:
            i_val = v
        elif num == 8:
            if wt == 2:
                j = 0
                while j < len(v):
                    d, j = _varint(v, j)
                    ints.append(d)
            else:
                ints.append(v)
    return name, (ints if ints else i_val)


def read_convs(path: Path) -> list[ConvNode]:
    """Every Conv node of the ONNX model at `path`, in graph order, with its weights."""
    path = Path(path)
    try:
        model = path.read_bytes()
        graph = next(v for num, wt, v in _fields(model) if num == 7 and wt == 2)
        inits, nodes = {}, []
        for num, wt, v in _fields(graph):
            if num == 5:
                name, arr = _tensor(v)
                inits[name] = arr
            elif num == 1:
                inputs, op, attrs, name = [], "", {}, ""
                for n2, _, v2 in _fields(v):
                    if n2 == 1:
                        inputs.append(v2.decode())
                    elif n2 == 3:
                        name = v2.decode()
                    elif n2 == 4:
                        op = v2.decode()
                    elif n2 == 5:
                        k, val = _attribute(v2)
                        attrs[k] = val
                nodes.append((op, name, inputs, attrs))
    except (OSError, StopIteration, ValueError, IndexError) as e:
        raise UserError(f"not a readable ONNX model ({e or 'no graph'})", where=str(path)) from None
    convs = []
    for op, name, inputs, attrs in nodes:
        if op != "Conv":
            continue
        if inputs[1] not in inits:
            raise UserError(f"Conv {name}: weight {inputs[1]} is not an initializer", where=str(path))
        bias = inits.get(inputs[2]) if len(inputs) > 2 else None
        convs.append(ConvNode(name, inits[inputs[1]], bias, attrs))
    return convs
