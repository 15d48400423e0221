"""Archive throughput: write 1,000,000 ImuSamples (10 units x 100,000, 0xCC at 100 Hz) through
ArchiveWriter one message at a time, then again in batches of each unit's samples
(``write_many``, --batch per call, as a recorder draining its queue does), then `gx3 export`
it to Parquet and `gx3 rrd` it to a Rerun recording.

    .venv/bin/python bench/bench_archive.py [--units 10] [--samples 100000] [--batch 100]

Prints samples/s written each way, bytes per sample on disk, the wall times of export and
rrd (with the load average: other work on the machine slows them all) and the .rrd's bytes
per sample. The values are a sensor at rest with realistic noise (float32 noise does not
compress much), so the size is close to what a real recording takes.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bridge.archive.writer import ArchiveWriter
from bridge.bus.codec import encode_batch
from bridge.protocol.codec import Batch
from bridge.protocol.convert import euler_to_m

T0 = 1_763_000_000_000_000_000
PERIOD_NS = 10_000_000


def unit_batch(n: int, seed: int) -> Batch:
    rng = np.random.default_rng(seed)
    euler = np.stack([rng.normal(0, 0.01, n), rng.normal(0, 0.01, n),
                      np.linspace(0, 2 * np.pi, n)], axis=1)
    columns = {
        "accel": (np.array([0.0, 0.0, -1.0]) + rng.normal(0, 0.002, (n, 3))).astype(np.float32),
        "ang_rate": rng.normal(0, 0.001, (n, 3)).astype(np.float32),
        "mag": (np.array([0.2, 0.0, 0.4]) + rng.normal(0, 0.001, (n, 3))).astype(np.float32),
        "m": euler_to_m(euler).astype(np.float32),
        "timer": (np.arange(n, dtype=np.uint32) * 625),
    }
    return Batch(0xCC, columns, np.arange(n), np.zeros(n, np.int64), False)


def load() -> str:
    """The machine's load over the last minute, so a figure says what else was running."""
    return f"load average {os.getloadavg()[0]:.2f}"


def gx3_seconds(command: str, archive: Path, out: Path) -> float:
    """Wall time of ``gx3 COMMAND ARCHIVE -o OUT`` as a user runs it (start-up included)."""
    gx3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or "gx3"
    start = time.perf_counter()
    subprocess.run([gx3, command, str(archive), "-o", str(out), "--force"], check=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=10)
    parser.add_argument("--samples", type=int, default=100_000, help="per unit")
    parser.add_argument("--batch", type=int, default=100,
                        help="samples of one unit per write_many call")
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: tmp)")
    args = parser.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="bench_archive_"))
    workdir.mkdir(parents=True, exist_ok=True)
    n, units = args.samples, args.units
    print(f"encoding {units} x {n:,} samples ...", flush=True)
    feeds = []
    for u in range(units):
        time_ns = T0 + np.arange(n, dtype=np.int64) * PERIOD_NS + u * 137_000
        payloads = encode_batch(f"imu{u}", unit_batch(n, u), np.arange(n, dtype=np.int64) * 625,
                                time_ns, time_ns + 2_000_000)
        feeds.append((f"gx3/imu{u}/imu", payloads, time_ns + 2_500_000))
    path = workdir / "bench.mcap"
    total = n * units
    one_by_one = [(key, payloads, rx.tolist()) for key, payloads, rx in feeds]
    start = time.perf_counter()
    # force: a re-run with the same --dir replaces its own files
    with ArchiveWriter(workdir / "one_by_one.mcap", force=True) as writer:
        for i in range(n):
            for key, payloads, received in one_by_one:
                writer.write(key, payloads[i], received[i])
    elapsed = time.perf_counter() - start
    print(f"write: {total:,} samples in {elapsed:.2f} s = {total / elapsed:,.0f} samples/s; "
          f"{load()}")
    start = time.perf_counter()
    with ArchiveWriter(path, force=True) as writer:
        for i in range(0, n, args.batch):
            for key, payloads, rx in feeds:
                writer.write_many(key, payloads[i : i + args.batch], rx[i : i + args.batch])
    elapsed = time.perf_counter() - start
    size = path.stat().st_size
    print(f"write_many ({args.batch} a call): {total:,} samples in {elapsed:.2f} s = "
          f"{total / elapsed:,.0f} samples/s; {writer.messages - total:,} frames and markers; "
          f"{size / 1e6:.1f} MB = {size / total:.1f} bytes/sample; {load()}")
    out = workdir / "bench.parquet"
    elapsed = gx3_seconds("export", path, out)
    print(f"gx3 export -> parquet: {elapsed:.2f} s ({total / elapsed:,.0f} samples/s), "
          f"{out.stat().st_size / 1e6:.1f} MB; {load()}")
    rrd = workdir / "bench.rrd"
    elapsed = gx3_seconds("rrd", path, rrd)
    print(f"gx3 rrd -> Rerun: {elapsed:.2f} s ({total / elapsed:,.0f} samples/s), "
          f"{rrd.stat().st_size / total:.0f} bytes/sample; {load()}")
    if args.dir is None:
        shutil.rmtree(workdir)


if __name__ == "__main__":
    main()
