"""A unit's measured noise (Kalibr's imu.yaml) as ROS covariances, and every way a noise
file or the options around it can be wrong: one line saying what to do, exit 2, before
anything is read or written."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from bridge.exceptions import Gx3Error, NoiseFileError
from bridge.ros2.noise import imu_covariance, read_noise, sample_variance
from bridge.sim.motion import Motion, MotionConfig
from tests.helpers.noise import (
    ACCEL_DENSITY,
    FILE_RATE_HZ,
    GYRO_DENSITY,
    kalibr_yaml,
    unit_samples,
)
from tests.helpers.processes import gx3


def test_the_kalibr_keys_are_read_and_any_other_key_is_ignored(tmp_path: Path) -> None:
    path = kalibr_yaml(tmp_path / "imu.yaml",
                       extra="allan_fit:\n  tau: [0.1, 1.0]\nunit_serial: '6234.1'\n")
    noise = read_noise(path)
    assert (noise.accel_noise_density, noise.gyro_noise_density) == (ACCEL_DENSITY,
                                                                     GYRO_DENSITY)
    assert (noise.accel_random_walk, noise.gyro_random_walk) == (3.0e-05, 4.0e-06)
    assert noise.update_rate_hz == FILE_RATE_HZ and noise.rostopic == "/gx3/u0/imu"
    provenance = noise.provenance()
    assert provenance["file"] == str(path) and len(str(provenance["sha256"])) == 64
    assert "allan_fit" not in provenance and "unit_serial" not in provenance


def test_variances_follow_the_rate_and_the_filter(tmp_path: Path) -> None:
    """σ² = N² · 1000 Hz / min(D, M) on the diagonal, 0 off it: N² · rate while the
    decimation D is at most the filter width M, N² · 1000 Hz / M once D > M. The
    orientation: all 0 (unknown, REP-145), or the square of a standard deviation given."""
    noise = read_noise(kalibr_yaml(tmp_path / "imu.yaml"))
    for rate, width, per_n2 in ((100.0, 15, 100.0), (1000.0, 15, 1000.0), (500.0, 2, 500.0),
                                (100.0, 4, 250.0), (1.0, 32, 1000.0 / 32)):
        cov = imu_covariance(noise, rate, width)
        assert (cov.rate_hz, cov.filter_width) == (rate, width)
        for values, density in ((cov.angular_velocity, GYRO_DENSITY),
                                (cov.linear_acceleration, ACCEL_DENSITY)):
            assert len(values) == 9
            assert [values[i] for i in (0, 4, 8)] == pytest.approx([density**2 * per_n2] * 3)
            assert [values[i] for i in (1, 2, 3, 5, 6, 7)] == [0.0] * 6
        assert cov.orientation == (0.0,) * 9
    assert imu_covariance(noise, 100.0, 15, 0.02).orientation == pytest.approx(
        (4e-4, 0, 0, 0, 4e-4, 0, 0, 0, 4e-4))
    unknown = imu_covariance(None, 100.0, 15, 0.02)
    assert unknown.angular_velocity == unknown.linear_acceleration == (0.0,) * 9
    for bad in ((noise, 0.0, 15), (noise, 100.0, 0)):
        with pytest.raises(ValueError, match="cannot give a variance"):
            imu_covariance(*bad)
    with pytest.raises(ValueError, match="cannot give a variance"):
        imu_covariance(noise, 100.0, 15, -0.1)


@pytest.mark.parametrize(("rate", "width"), [(200, 15), (250, 8), (100, 4), (50, 15)])
def test_the_variance_is_what_a_white_filter_needs_of_the_units_samples(
        rate: int, width: int) -> None:
    """What the covariance is for: a filter that takes the samples as white sums them, and
    a sum of n white samples of variance σ² varies by n σ². The emulated unit's samples
    (the sensor's density through its filter, every D-th cycle sent), summed a second at
    a time for 50 minutes: n σ² to 5 % with σ² = sample_variance, whether D < M (the
    samples share cycles) or D > M (they miss some)."""
    density = 1e-3
    samples = unit_samples(Motion(MotionConfig(seed=6, static=True,
                                               gyroscope_noise_density=density)),
                           rate, width, 3000)
    y = samples.join()[3].astype(np.float64)
    sums = y.reshape(-1, rate, 3).sum(axis=1)
    variance = sample_variance(density, rate, width)
    found = float(sums.var(axis=0).mean()) / rate
    assert found == pytest.approx(variance, rel=0.05)
    if 1000 // rate > width:  # independent samples: their own variance is the same number
        assert np.allclose(y.var(axis=0), variance, rtol=0.02)


@pytest.mark.parametrize(("content", "says"), [
    ("accelerometer_noise_density: [1\n", "not YAML"),
    ("- 1\n- 2\n", "a mapping of keys to values"),
    ("just text\n", "a mapping of keys to values"),
    ("", "a mapping of keys to values"),
    (b"\xff\xfe\x00".decode("latin-1"), "not YAML"),
])
def test_a_file_that_is_not_a_kalibr_yaml_is_refused(tmp_path: Path, content: str,
                                                     says: str) -> None:
    path = tmp_path / "imu.yaml"
    path.write_text(content, encoding="latin-1")
    with pytest.raises(NoiseFileError, match=says) as caught:
        read_noise(path)
    assert isinstance(caught.value, Gx3Error) and isinstance(caught.value, ValueError)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


@pytest.mark.parametrize("key", ["accelerometer_noise_density", "accelerometer_random_walk",
                                 "gyroscope_noise_density", "gyroscope_random_walk",
                                 "update_rate"])
def test_a_file_without_a_key_names_it(tmp_path: Path, key: str) -> None:
    path = kalibr_yaml(tmp_path / "imu.yaml", leave_out=key)
    with pytest.raises(NoiseFileError, match=f"lacks {key};"):
        read_noise(path)


@pytest.mark.parametrize(("line", "says"), [
    ("gyroscope_noise_density: fast", "not a number"),
    ("gyroscope_noise_density: true", "not a number"),
    ("gyroscope_noise_density: 0", "positive number"),
    ("gyroscope_noise_density: -1.0e-4", "positive number"),
    ("gyroscope_noise_density: .nan", "positive number"),
    ("update_rate: 0", "positive number"),
])
def test_a_value_that_is_not_a_positive_number_is_refused(tmp_path: Path, line: str,
                                                          says: str) -> None:
    key = line.split(":")[0]
    path = kalibr_yaml(tmp_path / "imu.yaml", leave_out=key, extra=line + "\n")
    with pytest.raises(NoiseFileError, match=says):
        read_noise(path)


def test_a_random_walk_of_zero_is_kept(tmp_path: Path) -> None:
    path = kalibr_yaml(tmp_path / "imu.yaml", leave_out="gyroscope_random_walk",
                       extra="gyroscope_random_walk: 0\n")
    assert read_noise(path).gyro_random_walk == 0.0


def _refused(done: subprocess.CompletedProcess[str], *says: str) -> None:
    stderr = done.stderr
    assert done.returncode == 2, stderr
    assert len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr, stderr
    assert stderr.startswith("error: ")
    for text in says:
        assert text in stderr, stderr


def test_gx3_export_refuses_a_bad_noise_file_in_one_line(tmp_path: Path) -> None:
    """Refused before the archive is read: a missing archive is not what it says."""
    bad = kalibr_yaml(tmp_path / "imu.yaml", leave_out="gyroscope_noise_density")
    out = tmp_path / "out.mcap"
    _refused(gx3("export", tmp_path / "none.mcap", "-o", out, "--noise", bad),
             "lacks gyroscope_noise_density")
    (tmp_path / "garbage.yaml").write_text("{{{\n")
    _refused(gx3("export", tmp_path / "none.mcap", "-o", out, "--noise",
                 tmp_path / "garbage.yaml"), "not YAML")
    _refused(gx3("export", tmp_path / "none.mcap", "-o", out, "--noise",
                 tmp_path / "absent.yaml"), "cannot read it")
    assert not out.exists()


def test_gx3_bridge_refuses_a_bad_noise_file_in_one_line(tmp_path: Path) -> None:
    """Refused before the port is opened or Zenoh started."""
    bad = kalibr_yaml(tmp_path / "imu.yaml", leave_out="update_rate")
    _refused(gx3("bridge", "--port", "/dev/null", "--ros2", "--noise", bad),
             "lacks update_rate")


@pytest.mark.parametrize(("args", "says"), [
    (["--noise", "{noise}"], "--noise is for the --ros2 topics: add --ros2"),
    (["--ros2-distro", "humble"], "--ros2-distro is for the --ros2 topics: add --ros2"),
    (["--orientation-stddev", "0.02"],
     "--orientation-stddev is for the --ros2 topics: add --ros2"),
    (["--ros2", "--ros2-distro", "iron"], "give humble or jazzy"),
])
def test_gx3_bridge_ros2_options_need_ros2_and_a_known_distro(
        tmp_path: Path, args: list[str], says: str) -> None:
    noise = kalibr_yaml(tmp_path / "imu.yaml")
    _refused(gx3("bridge", "--port", "/dev/null",
                 *[a.format(noise=noise) for a in args]), says)


def test_gx3_export_refuses_what_a_table_cannot_hold(tmp_path: Path) -> None:
    """A CSV file has no metadata to record the noise file or an orientation's standard
    deviation in; a table and a ROS 1 bag have no ROS 2 distribution; a format is
    written only to its own extension. Nothing is written."""
    noise = kalibr_yaml(tmp_path / "imu.yaml")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "t.csv", "--noise", noise),
             "a CSV file has no metadata", "write .parquet")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "t.parquet",
                 "--ros2-distro", "humble"), "--ros2-distro humble is for a ROS 2 bag")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "b.mcap",
                 "--ros2-distro", "rolling"), "give humble or jazzy")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "t.csv",
                 "--orientation-stddev", "0.02"), "--orientation-stddev is recorded in a "
             "Parquet table's metadata or used in a ROS bag")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "b.bag",
                 "--ros2-distro", "humble"), "a ROS 1 bag has Noetic's messages")
    _refused(gx3("export", tmp_path / "a.mcap", "-o", tmp_path / "b.bag", "--format", "ros2"),
             "--format ros2 writes a .mcap file; name the output b.mcap")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["imu.yaml"]
