"""Framing + decoding throughput of the reply codec, run by hand (not part of the tests).

    /work/venv/bin/python bench/bench_codec.py [--records N]

Streams of N records (default 1,000,000) are fed to ``Framer`` in 64 KiB chunks, as a
serial reader would, and in one piece. The time covers finding, checking and decoding
every record into columns; the best of 3 runs is reported, with peak traced memory
(tracemalloc, measured in a separate run because tracing slows allocation). The input
stream itself is built beforehand and not counted; fed in chunks, the framer's memory
does not grow with N, fed in one piece it holds a copy of the stream and its columns.
"""

from __future__ import annotations

import argparse
import functools
import gc
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bridge.protocol.codec import encode_replies
from bridge.protocol.framer import Framer
from bridge.protocol.table import REPLIES

CHUNK = 64 * 1024
REPEATS = 3


def stream(code: int, n: int, seed: int = 0) -> bytes:
    """n records of ``code`` with realistic values: unit vectors, rotation-ish matrices."""
    rng = np.random.default_rng(seed)
    columns: dict[str, np.ndarray] = {"timer": np.arange(n, dtype=np.uint64) * 625 % (1 << 32)}
    for f in REPLIES[code].fields:
        if f.name != "timer":
            columns[f.name] = rng.uniform(-1, 1, (n, *f.shape)).astype(np.float32)
    return encode_replies(code, columns, n)


def corrupt(data: bytes, size: int, fraction: float, seed: int = 1) -> tuple[bytes, int]:
    """Flip one random bit in ``fraction`` of the records; return the stream and how many."""
    rng = np.random.default_rng(seed)
    n = len(data) // size
    hit = rng.choice(n, int(n * fraction), replace=False)
    buf = np.frombuffer(data, np.uint8).copy()
    bits = rng.integers(0, 8 * size, len(hit))
    buf[hit * size + bits // 8] ^= (1 << (bits % 8)).astype(np.uint8)
    return buf.tobytes(), len(hit)


def frame_all(data: bytes, code: int, chunk: int | None) -> int:
    """Frame and decode ``data`` as a reader would, keeping only the record count."""
    framer = Framer([code])
    view = memoryview(data)
    count = 0
    step = chunk or len(data)
    for start in range(0, len(data), step):
        for batch in framer.feed(view[start : start + step]):
            count += len(batch)
    for batch in framer.flush():
        count += len(batch)
    return count


def best_time(fn: Callable[[], int]) -> tuple[float, int]:
    best, count = float("inf"), 0
    for _ in range(REPEATS):
        gc.collect()
        t0 = time.perf_counter()
        count = fn()
        best = min(best, time.perf_counter() - t0)
    return best, count


def peak_memory(fn: Callable[[], int]) -> int:
    gc.collect()
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


@dataclass
class Row:
    name: str
    feed: str
    records: int
    seconds: float
    nbytes: int
    peak: int

    def cells(self) -> list[str]:
        return [self.name, self.feed, f"{self.records:,}", f"{self.seconds * 1e3:,.0f}",
                f"{self.records / self.seconds / 1e6:.2f}",
                f"{self.nbytes / self.seconds / 1e6:,.0f}",
                f"{self.peak / 2**20:,.1f}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--records", type=int, default=1_000_000)
    n = parser.parse_args().records

    c8 = stream(0xC8, n)
    cases = [
        ("0xC8 clean", 0xC8, c8, n),
        ("0xCC clean", 0xCC, stream(0xCC, n), n),
    ]
    bad, hits = corrupt(c8, REPLIES[0xC8].length, 0.01)
    cases.append(("0xC8 1% flipped", 0xC8, bad, n - hits))

    rows = []
    for name, code, data, want in cases:
        for feed, chunk in (("64 KiB", CHUNK), ("1 piece", None)):
            run = functools.partial(frame_all, data, code, chunk)
            seconds, got = best_time(run)
            if got != want:
                raise SystemExit(f"{name}, {feed}: framed {got:,} records, expected {want:,}")
            peak = peak_memory(run)
            rows.append(Row(name, feed, got, seconds, len(data), peak))

    print(f"{n:,} records per stream, best of {REPEATS}; MB = 10^6 bytes of input")
    header = ["stream", "feed", "records", "ms", "Mrec/s", "MB/s", "peak MiB"]
    table = [header, *(r.cells() for r in rows)]
    widths = [max(len(line[i]) for line in table) for i in range(len(header))]
    for i, line in enumerate(table):
        print("  ".join(cell.rjust(w) if j >= 2 else cell.ljust(w)
                        for j, (cell, w) in enumerate(zip(line, widths, strict=True))))
        if i == 0:
            print("  ".join("-" * w for w in widths))


if __name__ == "__main__":
    main()
