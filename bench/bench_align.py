"""`gx3 align` on a fleet fixed to one body: its wall time and memory, and how right it is.

    .venv/bin/python bench/bench_align.py [--units 16] [--minutes 10] [--rate 500]
                                         [--dir DIR]

Writes (once; kept with --dir) an archive of --units units streaming 0xC2 at --rate for
--minutes, fixed to one body turned by hand, each turned its own way (a seeded random
rotation), 0.1 to 0.5 m from the first and archived late by its own 0 to 5 ms, with a
GX3's noise and biases: made in virtual time from the emulator's motion model. Prints,
with the load average (other work slows it all):

- `gx3 align` of every unit against the first as a user runs it (start-up included):
  wall seconds and the peak resident memory of the process;
- the worst error of the rotations, time shifts and lever arms it wrote, against the
  emulator's truth.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from procstat import gx3_run

from bridge.analysis.mounts import read_mounts
from bridge.archive.writer import ArchiveWriter
from bridge.protocol.convert import xyzw_to_rotation
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, Mounting, handheld

BODY_SEED = 11
WALL_NS = 1_763_000_000_000_000_000


def load() -> str:
    return f"load average {os.getloadavg()[0]:.2f}"


def mounting(unit: int) -> tuple[Mounting, float]:
    """Unit ``unit``'s seeded mounting, and how late (s) its samples are archived."""
    if unit == 0:
        return Mounting(BODY_SEED), 0.0
    rng = np.random.default_rng([BODY_SEED, unit])
    rotation = xyzw_to_rotation(rng.normal(size=4))
    direction = rng.normal(size=3)
    arm = direction / np.linalg.norm(direction) * rng.uniform(0.1, 0.5)
    return (Mounting(BODY_SEED, tuple(rotation.ravel().tolist()),
                     (float(arm[0]), float(arm[1]), float(arm[2]))),
            float(rng.uniform(0.0, 0.005)))


def body_archive(path: Path, units: int, minutes: float, rate: float) -> None:
    if path.exists():
        return
    start = time.perf_counter()
    times = np.arange(round(minutes * 60 * rate)) / rate
    with ArchiveWriter(path) as writer:
        for u in range(units):
            mount, late_s = mounting(u)
            config = handheld(MotionConfig(seed=u, accelerometer_noise_density=8e-4,
                                           gyroscope_noise_density=2e-4,
                                           gyro_bias_rad_s=(0.002, -0.001, 0.003),
                                           accel_bias_g=(0.002, 0.001, -0.002)), mount)
            archive_samples(writer, f"imu{u + 1}", Motion(config), times, 1 / rate,
                            wall_ns=WALL_NS + round(late_s * 1e9))
    print(f"wrote {path.name}: {units} x {len(times):,} samples, "
          f"{path.stat().st_size / 1e6:.0f} MB in {time.perf_counter() - start:.0f} s",
          flush=True)


def errors(path: Path, units: int) -> tuple[float, float, float]:
    """The worst rotation (deg), time shift (s) and lever arm (m) error of a mounts file."""
    mounts = read_mounts(path)
    worst = [0.0, 0.0, 0.0]
    for u in range(1, units):
        mount = mounts.units[f"imu{u + 1}"]
        truth, late_s = mounting(u)
        turn = mount.rotation @ truth.matrix.T
        worst[0] = max(worst[0], float(np.degrees(np.arccos(min(1.0, (np.trace(turn) - 1)
                                                                  / 2)))))
        worst[1] = max(worst[1], abs(mount.time_shift_s + late_s))
        if mount.lever_arm_m is not None:
            worst[2] = max(worst[2], float(np.abs(mount.lever_arm_m
                                                  - truth.lever_arm_m).max()))
    return worst[0], worst[1], worst[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, default=16)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=500.0)
    parser.add_argument("--dir", type=Path, default=None, help="where to write (default: tmp)")
    args = parser.parse_args()
    workdir = args.dir or Path(tempfile.mkdtemp(prefix="bench_align_"))
    workdir.mkdir(parents=True, exist_ok=True)
    archive = workdir / f"body_{args.units}x{args.minutes:g}min_{args.rate:g}Hz.mcap"
    body_archive(archive, args.units, args.minutes, args.rate)
    out = workdir / "mounts.yaml"
    names = [a for u in range(args.units) for a in ("-u", f"imu{u + 1}")]
    elapsed, peak = gx3_run("align", archive, *names, "-o", out)
    print(f"gx3 align, {args.units} units x {args.minutes:g} min at {args.rate:g} Hz: "
          f"{elapsed:.1f} s, peak {peak:.0f} MiB; {load()}", flush=True)
    rotation, shift, arm = errors(out, args.units)
    print(f"worst error against the truth: rotation {rotation:.4f} deg, time shift "
          f"{shift * 1e6:.1f} us, lever arm {arm * 1e3:.2f} mm", flush=True)
    if args.dir is None:
        shutil.rmtree(workdir)


if __name__ == "__main__":
    main()
