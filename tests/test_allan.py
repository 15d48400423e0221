"""`gx3 allan`: a still unit's noise read off its Allan deviation, against the emulator's truth.

Hours of a still unit are written straight into an archive in virtual time from the
emulator's motion model (``bridge.sim.archive_samples``), so a test takes seconds.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from ruamel.yaml import YAML

from bridge.analysis.allan import AllanSums, averaging_factors
from bridge.analysis.noise import (
    NOISE_KEYS,
    UnitNoise,
    UnitSamples,
    collect_samples,
    unit_noise,
    units_noise,
)
from bridge.archive.walk import read_samples_archive
from bridge.archive.writer import ArchiveWriter
from bridge.exceptions import CalibrationError, OptionError
from bridge.ros2.noise import imu_covariance, read_noise
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig
from bridge.sim.options import SimOptions
from tests.helpers.processes import gx3

RATE = 50.0  # Hz: the random walks need hours, not a high rate
#: the emulated unit's noise in Kalibr's units; the walks cross the white noise at ~17 s
TRUTH = {"accelerometer_noise_density": 2e-3, "accelerometer_random_walk": 2e-4,
         "gyroscope_noise_density": 1e-4, "gyroscope_random_walk": 1e-5}
STILL = MotionConfig(seed=3, static=True, accelerometer_noise_density=2e-3,
                     accelerometer_random_walk=2e-4, gyroscope_noise_density=1e-4,
                     gyroscope_random_walk=1e-5)


def _seconds(start: float, end: float) -> np.ndarray:
    return np.arange(round(start * RATE), round(end * RATE)) / RATE


def _noise(path: Path, unit: str = "u1") -> UnitNoise:
    kept, take, _ = collect_samples([unit])
    read_samples_archive(path, on_blocks=take)
    return unit_noise(kept[unit])


@pytest.fixture(scope="module")
def three_hours(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("allan") / "still.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "imu-1", Motion(STILL), _seconds(0, 3 * 3600), 1 / RATE)
    return path


def test_read_off_holds_to_the_truth(three_hours: Path, tmp_path: Path) -> None:
    out, plot = tmp_path / "imu.yaml", tmp_path / "allan.png"
    done = gx3("allan", three_hours, "-u", "imu-1", "-o", out, "--plot", plot)
    assert done.returncode == 0, done.stderr
    assert "warning" not in done.stderr and "wrote" in done.stderr
    found = YAML(typ="safe").load(out.read_text())
    # Kalibr's file: its four keys, the unit's ROS 2 topic as the export names it, the rate
    assert found["rostopic"] == "/gx3/imu_1/imu" and found["update_rate"] == RATE
    extra = found["gx3_allan"]
    for key in NOISE_KEYS:
        sensor, term = key.split("_", 1)
        axes = extra[sensor]
        assert found[key] == max(axes[term])  # the worst axis
        if term == "noise_density":
            assert np.allclose(axes[term], TRUTH[key], rtol=0.05), (key, axes[term])
        else:
            sigma = np.array(axes["random_walk_sigma"])
            assert not any(axes["random_walk_upper_bound"])
            assert (sigma < 0.15 * TRUTH[key]).all(), (key, sigma)
            assert (np.abs(np.array(axes[term]) - TRUTH[key]) < 3 * sigma).all(), (
                key, axes[term], sigma)
    assert extra["samples_used"] == 3 * 3600 * RATE and extra["stretches"] == 1
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the file is what --noise of the ROS 2 outputs takes: the same numbers come out
    cov = imu_covariance(read_noise(out), RATE)
    assert cov.angular_velocity[0] == found["gyroscope_noise_density"] ** 2 * RATE
    assert cov.linear_acceleration[8] == found["accelerometer_noise_density"] ** 2 * RATE


def test_gap_reset_and_rollover_split_the_series(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    motion = Motion(STILL)
    with ArchiveWriter(path) as writer:
        # the timer crosses its rollover 100 s in; the cable is pulled from 600 to 630 s;
        # the unit resets at 900 s (its timer from 0 again)
        start = 2**32 - 100 * 62_500
        archive_samples(writer, "u1", motion, _seconds(0, 600), 1 / RATE, timer_start=start)
        archive_samples(writer, "u1", motion, _seconds(630, 900), 1 / RATE, timer_start=start)
        archive_samples(writer, "u1", motion, _seconds(900, 1200), 1 / RATE,
                        timer_start=-900 * 62_500)
    noise = _noise(path)
    lengths = [n for _, _, n in noise.stretches]
    assert lengths == [100 * RATE, 500 * RATE, 270 * RATE, 300 * RATE]
    assert noise.used_samples == noise.samples == 1170 * RATE
    # bridged, the 30 s hole would add a step of the walk to the terms across it; cut, the
    # white noise still reads true
    assert np.allclose([a.noise_density for a in noise.gyroscope.axes], 1e-4, rtol=0.05)
    # too short for the walks: said, with how long to record
    assert any("record the unit still for 3 h" in w for w in noise.warnings)


def test_short_recording_warns_and_still_gives_the_densities(tmp_path: Path) -> None:
    path = tmp_path / "short.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 1200), 1 / RATE)
    out = tmp_path / "imu.yaml"
    done = gx3("allan", path, "-o", out)
    assert done.returncode == 0, done.stderr
    assert "warning: unit u1: only 0.33 h of still data" in done.stderr
    assert "record the unit still for 3 h or more" in done.stderr
    found = YAML(typ="safe").load(out.read_text())
    assert found["accelerometer_noise_density"] == pytest.approx(2e-3, rel=0.05)
    assert found["gyroscope_noise_density"] == pytest.approx(1e-4, rel=0.05)
    assert found["gx3_allan"]["warnings"]


def test_a_unit_that_moved_is_refused_saying_when(tmp_path: Path) -> None:
    path = tmp_path / "moved.mcap"
    moving = Motion(replace(STILL, static=False))
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 600), 1 / RATE)
        archive_samples(writer, "u1", moving, _seconds(600, 660), 1 / RATE)
        archive_samples(writer, "u1", Motion(STILL), _seconds(660, 1200), 1 / RATE)
    out = tmp_path / "imu.yaml"
    done = gx3("allan", path, "-o", out)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "unit u1 moved from 2025-11-13T02:23:20Z" in done.stderr
    assert "(600 s to 660 s into the span" in done.stderr and "--start/--end" in done.stderr
    assert not out.exists()
    # the still stretch before it is measured
    assert gx3("allan", path, "-o", out, "--end", "590").returncode == 0


def test_outputs_are_never_destroyed(tmp_path: Path) -> None:
    path = tmp_path / "short.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 120), 1 / RATE)
    out = tmp_path / "imu.yaml"
    out.write_text("mine\n")
    done = gx3("allan", path, "-u", "u1", "-o", out)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--force" in done.stderr and out.read_text() == "mine\n"
    assert gx3("allan", path, "-o", out, "--force").returncode == 0
    assert "accelerometer_noise_density" in out.read_text()
    # the archive itself is an input: never an output, whatever its name
    alias = tmp_path / "alias.yaml"
    os.link(path, alias)
    done = gx3("allan", path, "-u", "u1", "-o", alias, "--force")
    assert done.returncode == 2 and "is the input" in done.stderr, done.stderr
    assert path.read_bytes()[:8] == b"\x89MCAP0\r\n"


def test_a_corrupt_archive_is_a_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)
    done = gx3("allan", path, "-o", tmp_path / "imu.yaml")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "nothing readable" in done.stderr and "Traceback" not in done.stderr
    other = tmp_path / "notes.txt"
    other.write_text("not an archive\n")
    done = gx3("allan", other, "-o", tmp_path / "imu.yaml")
    assert done.returncode == 2 and "not an MCAP file" in done.stderr


def test_stretches_add_up_as_one_sum() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(0, 1, (5000, 2)), rng.normal(5, 1, (3000, 2))
    factors = averaging_factors(5000)
    both = AllanSums(factors, 2)
    both.add(a)
    both.add(b)
    apart = [AllanSums(factors, 2) for _ in range(2)]
    apart[0].add(a)
    apart[1].add(b)
    assert np.allclose(both.sums, apart[0].sums + apart[1].sums)
    assert (both.counts == apart[0].counts + apart[1].counts).all()
    # white noise of unit variance: the Allan variance at m samples is 1/m
    assert np.allclose(both.variance()[:5] * factors[:5, None], 1.0, rtol=0.1)


def _white(unit: str, seed: int, seconds: float = 600.0) -> UnitSamples:
    """A still unit's samples as ``collect_samples`` keeps them: white noise about 1 g."""
    rng = np.random.default_rng(seed)
    n = round(seconds * RATE)
    step = round(62_500 / RATE)
    accel = np.array([0.0, 0.0, -1.0]) + rng.normal(0, 1e-3, (n, 3))
    return UnitSamples(unit, [10**18 + np.arange(n, dtype=np.int64) * round(1e9 / RATE)],
                       [(np.arange(n) * step).astype(np.uint32)],
                       [accel.astype(np.float32)],
                       [rng.normal(0, 1e-4, (n, 3)).astype(np.float32)])


def test_units_shared_out_among_processes_give_what_each_gives_alone() -> None:
    """gx3 allan of a fleet: a unit a process, each result (or refusal) in its place."""
    units = [_white("u1", 1), UnitSamples("none"), _white("u2", 2), _white("u3", 3)]
    alone, shared = units_noise(units, jobs=1), units_noise(units, jobs=3)
    assert [type(r) for r in shared] == [UnitNoise, CalibrationError, UnitNoise, UnitNoise]
    assert str(shared[1]) == str(alone[1]) and "unit none has no samples" in str(shared[1])
    for one, other in zip(alone, shared, strict=True):
        if isinstance(one, UnitNoise):
            assert isinstance(other, UnitNoise) and other.unit == one.unit
            assert other.stretches == one.stretches
            for sensor in ("accelerometer", "gyroscope"):
                assert np.array_equal(getattr(other, sensor).adev, getattr(one, sensor).adev,
                                      equal_nan=True)


def test_the_emulator_noise_options_are_checked() -> None:
    with pytest.raises(OptionError, match="--gyro-random-walk"):
        SimOptions(pty=True, gyro_random_walk=-1.0).setup()
    motion = SimOptions(pty=True, accel_noise_density=0.002).setup().configs[0].motion
    assert motion.accelerometer_noise_density == 0.002
