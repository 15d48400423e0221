"""How fast the Rerun logger takes samples, at what CPU cost, and how big the .rrd gets.

Two runs, both writing an .rrd file through RerunLogger:

- paced: a live fleet, batches arriving in real time at --rate samples/s in total (the
  target is 100,000/s); reports the CPU used (all threads of the process, Rerun's own
  encoder included) as a share of one core.
- flat out: the same batches as fast as they go, as an archive conversion would;
  reports samples/s.

Each reports the file size per sample. Run by hand:
    .venv/bin/python bench/bench_viz.py [--units 100] [--rate 100000] [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.viz.demo import demo_columns
from bridge.viz.logger import RerunLogger

CODE = 0xCC  # accel, ang_rate, mag and M: the most a GX3-25 record holds


def batches(units: int, unit_rate: float, batch_s: float, seconds: float
            ) -> list[tuple[str, dict[str, np.ndarray]]]:
    """Each unit's columns cut in batches of batch_s, interleaved in arrival order. One
    second of motion is computed per unit and repeated with advancing ticks and times."""
    reps = int(np.ceil(seconds))
    per_batch = max(1, round(unit_rate * batch_s))
    cut: list[list[tuple[str, dict[str, np.ndarray]]]] = []
    for i in range(units):
        unit = f"imu{i}"
        one = demo_columns(unit, CODE, seed=i + 1, seconds=1.0, rate_hz=unit_rate)
        n = len(one["ticks"])
        cols = {k: np.concatenate([v] * reps) for k, v in one.items()}
        lap = np.repeat(np.arange(reps, dtype=np.int64), n)
        cols["ticks"] = cols["ticks"] + lap * TICKS_PER_SECOND
        cols["time_ns"] = cols["time_ns"] + lap * 1_000_000_000
        total = round(seconds * unit_rate)
        cut.append([(unit, {k: v[s:s + per_batch] for k, v in cols.items()})
                    for s in range(0, total, per_batch)])
    return [b for round_ in zip(*cut, strict=True) for b in round_]


def run(todo: list[tuple[str, dict[str, np.ndarray]]], path: Path, units: int,
        pace_s: float | None) -> dict[str, float]:
    """Log every batch (at one batch round per pace_s when pacing); wall and CPU time until
    the file is complete."""
    samples = sum(len(c["ticks"]) for _, c in todo)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    with RerunLogger(path, [f"imu{i}" for i in range(units)]) as log:
        for i, (unit, cols) in enumerate(todo):
            if pace_s is not None and i % units == 0:
                due = wall0 + (i // units) * pace_s
                delay = due - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            log.log_samples(unit, CODE, cols)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return {"samples": samples, "wall_s": wall, "cpu_s": cpu, "rate": samples / wall,
            "cores": cpu / wall, "bytes_per_sample": os.path.getsize(path) / samples}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=100, help="1,000 Hz each at the default rate")
    ap.add_argument("--rate", type=float, default=100_000.0, help="samples/s, all units")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--batch-ms", type=float, default=50.0, help="live batch length")
    args = ap.parse_args()
    unit_rate = args.rate / args.units
    todo = batches(args.units, unit_rate, args.batch_ms / 1000, args.seconds)
    with tempfile.TemporaryDirectory() as tmp:
        for label, pace in (("paced", args.batch_ms / 1000), ("flat out", None)):
            r = run(todo, Path(tmp) / "bench.rrd", args.units, pace)
            print(f"{label:8s}: {r['samples']:,.0f} samples (0x{CODE:02X}, {args.units} units x "
                  f"{unit_rate:,.0f} Hz, {args.batch_ms:g} ms batches) in {r['wall_s']:.2f} s "
                  f"-> {r['rate']:,.0f} samples/s, CPU {r['cpu_s']:.2f} s = "
                  f"{r['cores']:.2f} cores, {r['bytes_per_sample']:.1f} bytes/sample in .rrd")


if __name__ == "__main__":
    main()
