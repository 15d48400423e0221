"""Throughput of `gx3 decode` end to end, run by hand (not part of the tests).

    .venv/bin/python bench/bench_decode.py [--megabytes 100]

Writes a capture of 0xCC records (79 bytes each, the largest data record) to a
temporary file, then times the installed `gx3 decode FILE > /dev/null` as a
subprocess: reading, framing, decoding and writing one JSON line per record. The
best of 3 runs is reported as input MB/s (MB = 10^6 bytes).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_codec import stream

from bridge.protocol.table import REPLIES

REPEATS = 3


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--megabytes", type=float, default=100.0)
    n = int(parser.parse_args().megabytes * 1e6) // REPLIES[0xCC].length
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent))
    if gx3 is None:
        raise SystemExit("gx3 is not installed next to this interpreter")
    with tempfile.TemporaryDirectory() as tmp:
        capture = Path(tmp) / "cc.bin"
        capture.write_bytes(stream(0xCC, n))
        size = capture.stat().st_size
        best = float("inf")
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            with open("/dev/null", "wb") as sink:
                done = subprocess.run([gx3, "decode", str(capture)], stdout=sink,
                                      stderr=subprocess.PIPE, check=False)
            best = min(best, time.perf_counter() - t0)
            if done.returncode != 0:
                raise SystemExit(f"gx3 decode failed: {done.stderr.decode().strip()}")
        summary = done.stderr.decode().strip()
    if f"0xCC×{n}" not in summary:
        raise SystemExit(f"expected {n:,} records, got: {summary}")
    print(f"{n:,} 0xCC records, {size / 1e6:.0f} MB: best of {REPEATS} {best:.2f} s, "
          f"{size / best / 1e6:.1f} MB/s of input, {n / best / 1e3:.0f} k records/s")


if __name__ == "__main__":
    main()
