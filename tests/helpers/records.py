"""Batches of records built for tests, and the bus payloads they encode to."""

from __future__ import annotations

import numpy as np

from bridge.bus.codec import encode_batch
from bridge.protocol.codec import Batch, decode_block, encode_replies
from bridge.protocol.convert import euler_to_m, euler_to_quaternion
from bridge.protocol.table import REPLIES

T0 = 1_763_000_000_000_000_000  # 2025-11-13 02:13:20 UTC: where built samples' times start
CODE = 0xC2  # the record built when any will do (acceleration and angular rate)


def synthetic_batch(code: int, n: int, seed: int, euler: np.ndarray | None = None) -> Batch:
    """n records of ``code`` with random values; attitude fields follow ``euler`` if given."""
    rng = np.random.default_rng(seed)
    columns: dict[str, np.ndarray] = {}
    for f in REPLIES[code].fields:
        if f.name == "timer":
            columns["timer"] = (np.arange(n, dtype=np.uint32) * 625 + seed).astype(np.uint32)
        elif f.kind == "u16":
            columns[f.name] = rng.integers(0, 4096, (n, *f.shape)).astype(np.uint16)
        else:
            columns[f.name] = rng.normal(0, 1, (n, *f.shape)).astype(np.float32)
    if euler is not None:
        attitude = {"m": euler_to_m(euler), "quaternion": euler_to_quaternion(euler),
                    "euler": euler}
        for name, values in attitude.items():
            if name in columns:
                columns[name] = values.astype(np.float32)
    return Batch(code, columns, np.arange(n), np.zeros(n, np.int64), False)


def wire_batch(code: int, n: int, seed: int) -> Batch:
    """n records of ``code`` as the framer hands them out, through the wire codec."""
    rng = np.random.default_rng(seed)
    columns: dict[str, np.ndarray] = {}
    for f in REPLIES[code].fields:
        if f.kind == "f32":
            values = rng.normal(0, 3, (n, *f.shape)).astype(np.float32)
            values.reshape(n, -1)[0, 0] = np.nan  # idle units send NaN
            columns[f.name] = values
        elif f.name == "timer":
            columns[f.name] = np.array([0, 2**32 - 1, *range(1, n - 1)], np.uint32)
        else:
            columns[f.name] = rng.integers(0, 4096, (n, *f.shape)).astype(np.uint16)
    raw = encode_replies(code, columns, n)
    block = np.frombuffer(raw, np.uint8).reshape(n, -1)
    offsets = np.arange(n) * REPLIES[code].length
    return Batch(code, decode_block(code, block), offsets, np.zeros(n, np.int64), False)


def wire_times(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ticks (0, -1, 2**40, then 0, 1, ...), times 1 ms apart and receive times 2.5 ms
    later, for ``n`` records."""
    ticks = np.array([0, -1, 2**40, *range(n - 3)], np.int64)
    time_ns = T0 + np.arange(n, dtype=np.int64) * 1_000_000
    return ticks, time_ns, time_ns + 2_500_000


def indexed_batch(start: int, n: int) -> tuple[Batch, np.ndarray, np.ndarray]:
    """``n`` records of ``CODE`` from index ``start``: ticks 625 apart (100 Hz), values =
    index."""
    index = np.arange(start, start + n, dtype=np.int64)
    columns = {f.name: np.repeat(index.astype(np.float32), int(np.prod(f.shape))).reshape(
        n, *f.shape) for f in REPLIES[CODE].fields}
    columns["timer"] = (index * 625).astype(np.uint32)
    times = T0 + index * 10_000_000
    return Batch(CODE, columns, index, times, False), index * 625, times


def indexed_payloads(unit: str, start: int, n: int) -> list[bytes]:
    """``indexed_batch(start, n)`` as ``unit``'s ImuSample payloads."""
    records, ticks, times = indexed_batch(start, n)
    return encode_batch(unit, records, ticks, times, times)
