"""TensorFlow checkpoints (tensor bundles) read and written with numpy alone, for the ACNe weights.

:func:`read_tf_checkpoint` / :func:`write_tf_checkpoint`: a prefix ``P`` with ``P.index``, a LevelDB-style
table (TensorFlow's ``core/lib/io/table``) of ``BundleEntryProto`` per tensor name, and ``P.data-*``, the
raw little-endian bytes. Compressed tables and partitioned tensors raise ``ValueError``.
"""

from __future__ import annotations

import os
import struct
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["read_tf_checkpoint", "write_tf_checkpoint", "resolve_tf_prefix"]

_MAGIC = 0xDB4775248B80FB57
_FOOTER = 48
# tensorflow/core/framework/types.proto DataType -> numpy little-endian dtype.
_DTYPES = {1: "<f4", 2: "<f8", 3: "<i4", 4: "u1", 5: "<i2", 6: "i1", 9: "<i8", 10: "?", 17: "<u2",
           19: "<f2", 22: "<u4", 23: "<u8"}
_DTYPE_CODES = {np.dtype(v): k for k, v in _DTYPES.items()}


# ------------------------------------------------------------------------------------------ CRC32C
@lru_cache(maxsize=1)
def _crc_table() -> list[int]:
    poly = 0x82F63B78  # Castagnoli, reflected
    table = np.arange(256, dtype=np.uint64)
    for _ in range(8):
        table = np.where(table & 1, (table >> 1) ^ poly, table >> 1)
    return [int(v) for v in table]


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli) of ``data``; pure Python, for the small blocks of an index file."""
    t = _crc_table()
    crc = 0xFFFFFFFF
    for b in data:
        crc = t[(crc ^ b) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def _mask(crc: int) -> int:
    return ((((crc >> 15) | (crc << 17)) & 0xFFFFFFFF) + 0xA282EAD8) & 0xFFFFFFFF


# ------------------------------------------------------------------------------------ varints, protos
def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint in TensorFlow checkpoint index")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _enc_varint(v: int) -> bytes:
    out = bytearray()
    while v > 0x7F:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _proto_fields(buf: bytes) -> list[tuple[int, int, object]]:
    """(field number, wire type, value) of a serialised protobuf message, in order."""
    out, pos = [], 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            val, pos = _varint(buf, pos)
        elif wire == 1:
            val, pos = struct.unpack_from("<Q", buf, pos)[0], pos + 8
        elif wire == 2:
            n, pos = _varint(buf, pos)
            val, pos = buf[pos: pos + n], pos + n
        elif wire == 5:
            val, pos = struct.unpack_from("<I", buf, pos)[0], pos + 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire} in TensorFlow checkpoint index")
        out.append((field, wire, val))
    return out


def _enc_field(field: int, wire: int, val) -> bytes:
    key = _enc_varint((field << 3) | wire)
    if wire == 0:
        return key + _enc_varint(int(val))
    if wire == 2:
        return key + _enc_varint(len(val)) + bytes(val)
    if wire == 5:
        return key + struct.pack("<I", int(val))
    raise ValueError(wire)


def _parse_entry(buf: bytes) -> dict:
    entry = {"dtype": 0, "shape": [], "shard_id": 0, "offset": 0, "size": 0, "sliced": False}
    scalars = {1: "dtype", 3: "shard_id", 4: "offset", 5: "size"}  # BundleEntryProto field numbers
    for field, _, val in _proto_fields(buf):
        if field in scalars:
            entry[scalars[field]] = val
        elif field == 2:
            for f2, _, dim in _proto_fields(val):
                if f2 == 2:  # TensorShapeProto.dim
                    size = next((v for f3, _, v in _proto_fields(dim) if f3 == 1), 0)
                    entry["shape"].append(size - (1 << 64) if size >= 1 << 63 else size)
                elif f2 == 3 and val:
                    raise ValueError("TensorFlow checkpoint holds a tensor of unknown rank")
        elif field == 7:
            entry["sliced"] = True
    return entry


# --------------------------------------------------------------------------------------------- table
def _read_block(data: bytes, offset: int, size: int) -> list[tuple[bytes, bytes]]:
    if offset + size + 5 > len(data):
        raise ValueError("TensorFlow checkpoint index is truncated (block past the end of the file)")
    if data[offset + size] != 0:
        raise ValueError(f"compressed TensorFlow checkpoint index blocks (type {data[offset + size]}) are not "
                         "supported")
    block = data[offset: offset + size]
    n_restarts = struct.unpack_from("<I", block, len(block) - 4)[0]
    end = len(block) - 4 - 4 * n_restarts
    entries, pos, key = [], 0, b""
    while pos < end:
        shared, pos = _varint(block, pos)
        non_shared, pos = _varint(block, pos)
        vlen, pos = _varint(block, pos)
        key = key[:shared] + block[pos: pos + non_shared]
        pos += non_shared
        entries.append((key, block[pos: pos + vlen]))
        pos += vlen
    return entries


def _table_entries(index: bytes) -> list[tuple[bytes, bytes]]:
    if len(index) < _FOOTER or struct.unpack_from("<Q", index, len(index) - 8)[0] != _MAGIC:
        raise ValueError("not a TensorFlow checkpoint index (bad magic number)")
    footer = index[len(index) - _FOOTER:]
    _, pos = _varint(footer, 0)  # meta-index offset
    _, pos = _varint(footer, pos)  # meta-index size
    idx_off, pos = _varint(footer, pos)
    idx_size, pos = _varint(footer, pos)
    out = []
    for _, handle in _read_block(index, idx_off, idx_size):
        off, p = _varint(handle, 0)
        size, _ = _varint(handle, p)
        out.extend(_read_block(index, off, size))
    return out


def _block(entries: list[tuple[bytes, bytes]]) -> bytes:
    body = bytearray()
    restarts = []
    for key, value in entries:  # every entry a restart point: no prefix sharing, simplest valid layout
        restarts.append(len(body))
        body += _enc_varint(0) + _enc_varint(len(key)) + _enc_varint(len(value)) + key + value
    restarts = restarts or [0]
    return bytes(body + struct.pack(f"<{len(restarts) + 1}I", *restarts, len(restarts)))


def _with_trailer(block: bytes) -> bytes:
    return block + b"\x00" + struct.pack("<I", _mask(crc32c(block + b"\x00")))


# ----------------------------------------------------------------------------------------------- API
def resolve_tf_prefix(path) -> Path:
    """The checkpoint prefix ``P`` from ``P``, ``P.index``, ``P.data-…`` or a folder (through its
    ``checkpoint`` state file, else its single ``*.index`` file)."""
    path = Path(path)
    if path.is_dir():
        state = path / "checkpoint"
        if state.is_file():
            for line in state.read_text(encoding="utf-8").splitlines():
                if line.startswith("model_checkpoint_path:"):
                    name = line.split(":", 1)[1].strip().strip('"')
                    p = Path(name)
                    return p if p.is_absolute() else path / p
        found = sorted(path.glob("*.index"))
        if len(found) != 1:
            raise ValueError(f"weights folder {path} must hold exactly one TensorFlow *.index file or a "
                             f"'checkpoint' state file, found {len(found)} index files")
        return found[0].with_suffix("")
    name = path.name
    if name.endswith(".index"):
        return path.with_name(name[: -len(".index")])
    if ".data-" in name:
        return path.with_name(name.split(".data-")[0])
    return path


def read_tf_checkpoint(path) -> dict[str, np.ndarray]:
    """Every numeric tensor of the TensorFlow checkpoint at ``path`` (:func:`resolve_tf_prefix`) by name.

    ``FileNotFoundError`` for a missing index or shard; ``ValueError`` for anything else unreadable.
    """
    prefix = resolve_tf_prefix(path)
    index_path = prefix.with_name(prefix.name + ".index")
    if not index_path.is_file():
        raise FileNotFoundError(f"TensorFlow checkpoint index not found: {index_path}")
    entries = _table_entries(index_path.read_bytes())
    num_shards = 1
    tensors: dict[str, np.ndarray] = {}
    shards: dict[int, bytes] = {}
    for key, value in entries:
        if key == b"":
            for field, _, val in _proto_fields(value):
                if field == 1:
                    num_shards = val
                elif field == 2 and val != 0:
                    raise ValueError("big-endian TensorFlow checkpoints are not supported")
            continue
        e = _parse_entry(value)
        if e["sliced"]:
            raise ValueError(f"partitioned tensor {key.decode()!r} in TensorFlow checkpoint is not supported")
        if e["dtype"] not in _DTYPES:
            continue  # strings, resources: nothing a network weight needs
        if e["shard_id"] not in shards:
            data = prefix.with_name(f"{prefix.name}.data-{e['shard_id']:05d}-of-{num_shards:05d}")
            if not data.is_file():
                raise FileNotFoundError(f"TensorFlow checkpoint data shard not found: {data}")
            shards[e["shard_id"]] = data.read_bytes()
        raw = shards[e["shard_id"]][e["offset"]: e["offset"] + e["size"]]
        dtype = np.dtype(_DTYPES[e["dtype"]])
        n = int(np.prod(e["shape"], dtype=np.int64)) if e["shape"] else 1
        if len(raw) != n * dtype.itemsize:
            raise ValueError(f"tensor {key.decode()!r}: {len(raw)} bytes stored, shape {e['shape']} needs "
                             f"{n * dtype.itemsize}")
        tensors[key.decode()] = np.frombuffer(raw, dtype).reshape(e["shape"]).astype(dtype.newbyteorder("="))
    return tensors


def write_tf_checkpoint(prefix, tensors: dict[str, np.ndarray]) -> Path:
    """Write ``tensors`` (name -> numeric array) as ``prefix.index`` + ``prefix.data-00000-of-00001``.

    Returns ``prefix`` (its folder must exist), readable by TensorFlow's ``tf.train.load_checkpoint``.
    """
    prefix = Path(prefix)
    data = bytearray()
    entries = []
    for name in sorted(tensors):
        arr = np.asarray(tensors[name])  # not ascontiguousarray: it turns scalars into shape (1,)
        code = _DTYPE_CODES.get(arr.dtype.newbyteorder("<"))
        if code is None:
            raise ValueError(f"tensors[{name!r}] has unsupported dtype {arr.dtype}")
        raw = arr.astype(np.dtype(_DTYPES[code])).tobytes(order="C")
        shape = b"".join(_enc_field(2, 2, _enc_field(1, 0, d)) for d in arr.shape)
        proto = (_enc_field(1, 0, code) + _enc_field(2, 2, shape) + _enc_field(4, 0, len(data))
                 + _enc_field(5, 0, len(raw)) + _enc_field(6, 5, _mask(crc32c(raw))))
        entries.append((name.encode(), proto))
        data += raw
    # Header: one shard, little endian, version {producer: 1}.
    header = _enc_field(1, 0, 1) + _enc_field(3, 2, _enc_field(1, 0, 1))
    # The index file: data block, meta-index block (empty), index block, footer (block handles, magic).
    data_block = _with_trailer(_block([(b"", header)] + entries))
    meta_block = _with_trailer(_block([]))
    last_key = entries[-1][0] if entries else b""
    index_block = _with_trailer(_block([(last_key, _enc_varint(0) + _enc_varint(len(data_block) - 5))]))
    footer = (_enc_varint(len(data_block)) + _enc_varint(len(meta_block) - 5)
              + _enc_varint(len(data_block) + len(meta_block)) + _enc_varint(len(index_block) - 5))
    index = data_block + meta_block + index_block + footer + b"\x00" * (40 - len(footer)) + struct.pack("<Q", _MAGIC)
    _write(prefix.with_name(prefix.name + ".data-00000-of-00001"), bytes(data))
    _write(prefix.with_name(prefix.name + ".index"), index)
    return prefix


def _write(path: Path, payload: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        f.write(payload)
    os.replace(tmp, path)
