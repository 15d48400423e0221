"""`gx3 allan` on hours of a still unit: its wall time and memory, the Allan core against
allantools, and a fleet archive shared out a unit a process.

    .venv/bin/python bench/bench_allan.py [--hours 8] [--rate 1000] [--units 16]
                                         [--fleet-hours 1] [--fleet-rate 100] [--dir DIR]

Writes (once; kept with --dir) an archive of one still unit streaming 0xC2 for --hours
at --rate, made in virtual time from the emulator's noise model through the factory's
filter (width 15), and one of --units units for --fleet-hours each at --fleet-rate.
Prints, with the load average (other work slows it all):

- `gx3 allan` of the one unit as a user runs it (start-up included): wall seconds and
  the peak resident memory of the process;
- the overlapping Allan deviation alone of its six axes on the same taus: this
  project's cumulative-sum version (``bridge.analysis.allan``) against allantools'
  ``oadev`` (``pip install allantools==2024.6``; skipped when it is not installed),
  seconds and peak memory (tracemalloc) of each;
- `gx3 allan` of every unit of the fleet archive, with one process per core and with one.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from procstat import gx3_run, load

from bridge.analysis.allan import AllanSums, averaging_factors
from bridge.analysis.noise import collect_samples
from bridge.archive.walk import read_samples_archive
from bridge.archive.writer import ArchiveWriter
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig


def still_archive(path: Path, units: int, hours: float, rate: float) -> None:
    if path.exists():
        return
    start = time.perf_counter()
    with ArchiveWriter(path) as writer:
        for u in range(units):
            config = MotionConfig(seed=u, static=True, accelerometer_noise_density=2e-3,
                                  accelerometer_random_walk=2e-4, gyroscope_noise_density=1e-4,
                                  gyroscope_random_walk=1e-5)
            motion = Motion(config)
            hour = round(3600 * rate)  # an hour at a time: the times of 8 h are 230 MB
            for first in range(0, round(hours * 3600 * rate), hour):
                times = np.arange(first, min(first + hour, round(hours * 3600 * rate))) / rate
                archive_samples(writer, f"imu{u}", motion, times, 1 / rate)
    print(f"wrote {path.name}: {units} x {round(hours * 3600 * rate):,} samples, "
          f"{path.stat().st_size / 1e6:.0f} MB in {time.perf_counter() - start:.0f} s",
          flush=True)


def core(path: Path) -> None:
    """The Allan deviation alone, ours against allantools, on the one unit's six axes."""
    kept, take, _ = collect_samples(None)
    read_samples_archive(path, on_blocks=take)
    unit = next(iter(kept.values()))
    _, timer, accel, gyro = unit.join()  # float32, as gx3 allan keeps them
    rate = 62_500 / float(np.median(np.diff(timer.astype(np.int64))))
    factors = averaging_factors(len(accel))
    tracemalloc.start()
    start = time.perf_counter()
    sums = AllanSums(factors, 6)
    sums.add(accel, gyro)
    ours = np.sqrt(sums.variance())
    elapsed = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    print(f"Allan core, cumulative sums: {elapsed:.2f} s, peak {peak:.0f} MiB for "
          f"{len(accel):,} x 6 ({len(factors)} taus); {load()}", flush=True)
    try:
        import allantools  # only for the comparison: not a dependency
    except ImportError:
        print("allantools not installed: pip install allantools==2024.6 to compare")
        return
    tracemalloc.start()
    start = time.perf_counter()
    theirs = np.column_stack([
        allantools.oadev(np.asarray(column, np.float64), rate=rate, data_type="freq",
                         taus=factors / rate)[1]
        for part in (accel, gyro) for column in part.T])
    elapsed = time.perf_counter() - start
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    agree = np.nanmax(np.abs(theirs / ours[: len(theirs)] - 1))
    print(f"Allan core, allantools.oadev: {elapsed:.2f} s, peak {peak:.0f} MiB; largest "
          f"relative difference {agree:.1e} (ours: starts m/16 apart past m = 31); {load()}",
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--fleet-hours", type=float, default=1.0)
    parser.add_argument("--fleet-rate", type=float, default=100.0)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: tmp)")
    args = parser.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="bench_allan_"))
    workdir.mkdir(parents=True, exist_ok=True)
    one = workdir / f"still_{args.hours:g}h_{args.rate:g}hz.mcap"
    still_archive(one, 1, args.hours, args.rate)
    elapsed, peak = gx3_run("allan", one, "-o", workdir / "imu.yaml")
    print(f"gx3 allan, 1 unit x {args.hours:g} h at {args.rate:g} Hz: {elapsed:.1f} s, peak "
          f"{peak:.0f} MiB; {load()}", flush=True)
    core(one)
    fleet = workdir / f"fleet_{args.units}x{args.fleet_hours:g}h_{args.fleet_rate:g}hz.mcap"
    still_archive(fleet, args.units, args.fleet_hours, args.fleet_rate)
    for jobs in (None, 1):
        extra = () if jobs is None else ("-j", str(jobs))
        elapsed, peak = gx3_run("allan", fleet, "-o", workdir / "imu_{unit}.yaml", *extra)
        print(f"gx3 allan, {args.units} units x {args.fleet_hours:g} h, "
              f"{'one process per core' if jobs is None else 'one process'}: "
              f"{elapsed:.1f} s, peak {peak:.0f} MiB (largest process); {load()}", flush=True)
    if args.dir is None:
        shutil.rmtree(workdir)


if __name__ == "__main__":
    main()
