"""Kalibr ``imu.yaml`` files as `gx3 allan` writes them, for the covariance tests."""

from __future__ import annotations

from pathlib import Path

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
