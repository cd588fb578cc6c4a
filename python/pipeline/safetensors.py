"""Reads a .safetensors file with NumPy alone (the format: an 8-byte little-endian header
length, a JSON header of name -> dtype, shape, byte offsets, then the raw tensors)."""

import json
import struct

import numpy as np

_DTYPES = {"F32": np.float32, "F64": np.float64, "F16": np.float16, "I64": np.int64, "I32": np.int32,
           "I16": np.int16, "I8": np.int8, "U8": np.uint8, "BOOL": np.bool_}


def load_safetensors(path):
    """(tensors, metadata): a dict of name -> NumPy array, and the file's ``__metadata__``."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 8:
        raise ValueError(f"{path}: not a safetensors file (shorter than its header length)")
    (n,) = struct.unpack("<Q", data[:8])
    if n > len(data) - 8:
        raise ValueError(f"{path}: not a safetensors file (header of {n} bytes in a file of {len(data)})")
    header = json.loads(data[8:8 + n])
    meta = header.pop("__metadata__", {}) or {}
    body = memoryview(data)[8 + n:]
    out = {}
    for name, t in header.items():
        if t["dtype"] not in _DTYPES:
            raise ValueError(f"{path}: {name} has dtype {t['dtype']}, which this reader does not know")
        a, b = t["data_offsets"]
        out[name] = np.frombuffer(body[a:b], dtype=np.dtype(_DTYPES[t["dtype"]]).newbyteorder("<")).reshape(t["shape"]).copy()
    return out, meta
