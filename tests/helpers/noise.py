"""Kalibr ``imu.yaml`` files as `gx3 allan` writes them, and a still unit's samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bridge.analysis.noise import UnitSamples
from bridge.sim.motion import Motion, SignalChain

WALL_NS = 1_763_000_000_000_000_000  # host time at device time 0

#: Densities of the GX3's order of magnitude, in Kalibr's units, and a rate that is not
#: the emulated units' (100 Hz), so that a test tells which one was used.
ACCEL_DENSITY = 8.0e-4  # m/s²/√Hz
GYRO_DENSITY = 6.0e-5  # rad/s/√Hz
FILE_RATE_HZ = 200.0


def kalibr_yaml(path: Path, *, extra: str = "", leave_out: str = "") -> Path:
    """Write a Kalibr imu.yaml: the five numbers, rostopic, ``extra`` lines; without the
    line of key ``leave_out``."""
    lines = [f"accelerometer_noise_density: {ACCEL_DENSITY:.2e}",
             "accelerometer_random_walk: 3.0e-05",
             f"gyroscope_noise_density: {GYRO_DENSITY:.2e}",
             "gyroscope_random_walk: 4.0e-06",
             "rostopic: /gx3/u0/imu",
             f"update_rate: {FILE_RATE_HZ}"]
    kept = [line for line in lines if not (leave_out and line.startswith(leave_out + ":"))]
    path.write_text("\n".join(kept) + "\n" + extra)
    return path


def unit_samples(motion: Motion, rate_hz: float, width: int, seconds: float,
                 unit: str = "u1", start_s: float = 0.0) -> UnitSamples:
    """What ``collect_samples`` keeps of a unit streaming 0xC2 at ``rate_hz`` through the
    filter of ``width``, straight from the emulator's motion (no archive in between)."""
    decimation = round(1000 / rate_hz)
    cycles = round(start_s * 1000) + np.arange(round(seconds * rate_hz)) * decimation
    out = UnitSamples(unit, settings=[(WALL_NS, width, decimation)])
    for at in range(0, len(cycles), 200_000):
        t = cycles[at : at + 200_000] / 1000
        s = motion.sample(t, decimation / 1000, SignalChain(width, 17, True),
                          only=("accel", "ang_rate"))
        out.add(WALL_NS + cycles[at : at + 200_000] * 1_000_000,
                (np.round(t * 62_500).astype(np.int64) % 2**32).astype(np.uint32),
                s["accel"], s["ang_rate"])
    return out
