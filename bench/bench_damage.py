"""What one flipped byte costs: an archive of UNITS units of 0xCC samples at 100 Hz for
MINUTES (default chunks of 1 MiB), a byte flipped at 25 %, 50 % and 75 % of it, read
back. Prints the messages and samples lost each time, and the span of log time lost.

    .venv/bin/python bench/bench_damage.py [--units 2] [--minutes 10]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from bench_archive import PERIOD_NS, T0, unit_batch

from bridge.archive.walk import read_archive
from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=2)
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()
    n = int(args.minutes * 60 * 1e9 / PERIOD_NS)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp, "a.mcap")
        with ArchiveWriter(path) as writer:
            feeds = []
            for u in range(args.units):
                t = T0 + np.arange(n, dtype=np.int64) * PERIOD_NS + u * 137_000
                payloads = encode_batch(f"imu{u}", unit_batch(n, u), np.arange(n) * 625, t,
                                        t + 2_000_000)
                feeds.append((f"gx3/imu{u}/imu", payloads, t + 2_500_000))
            for lo in range(0, n, 100):  # a second at a time, as a recorder takes them
                for key, payloads, rx in feeds:
                    writer.write_many(key, payloads[lo : lo + 100], rx[lo : lo + 100])
        full = read_archive(path)
        samples = sum(len(s) for s in full.samples())
        print(f"{path.stat().st_size / 1e6:.1f} MB, {full.message_count:,} messages "
              f"({samples:,} samples) in {full.chunks} chunks")
        data = path.read_bytes()
        for share in (0.25, 0.5, 0.75):
            flipped = bytearray(data)
            flipped[int(len(data) * share)] ^= 0xFF
            damaged_path = Path(tmp, "flipped.mcap")
            damaged_path.write_bytes(bytes(flipped))
            damaged = read_archive(damaged_path, warn=lambda _: None)
            kept = sum(len(s) for s in damaged.samples())
            span = sum(d.end_ns - d.start_ns for d in damaged.damage) / 1e9
            print(f"byte flipped at {share:.0%}: {full.message_count - damaged.message_count:,}"
                  f" messages lost ({samples - kept:,} samples, {span:.1f} s of log time, "
                  f"{len(damaged.damage)} chunk)")


if __name__ == "__main__":
    main()
