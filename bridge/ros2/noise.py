"""A unit's measured sensor noise (Kalibr's ``imu.yaml``), and the covariances it gives.

``gx3 allan`` (or Kalibr's own tools) writes the white-noise densities and bias random
walks of a unit's accelerometers and gyros as Kalibr's ``imu.yaml``: ``gx3 allan``'s
are the sensor's own, whatever rate and filter width they were measured at. A ROS
consumer wants the variance of one sample instead, for a filter that takes the samples
as white. That depends on the unit's filter as well as its rate (``sample_variance``):
a GX3 averages M calculation cycles (1 kHz, each of variance N² · 1000 Hz after the
fixed first stage) and sends every D-th. When D <= M, neighbouring samples share cycles
and are not white; the white-equivalent variance, the one that gives the density N
over time, is N² · rate (their own, N² · 1000 Hz / M, is smaller, and their correlation
makes up the rest). When D > M, they share none and are independent, each of variance
N² · 1000 Hz / M: more than N² · rate, since each misses D - M of its D cycles. One
formula holds both: σ² = N² · 1000 Hz / min(D, M). The rate and width are the unit's
own (1000 Hz / decimation and the filter width, from its Info), not the file's
``update_rate``: the samples the messages carry come with them.

An orientation has no such measurement: the 3DM-GX3 manual states no attitude accuracy
for any model. REP-145 makes an unknown covariance all zeros unless a parameter
overrides it (``orientation_stddev``, as MicroStrain's, Xsens's and VectorNav's ROS
drivers take one); element 0 of -1 says instead that a message has no orientation at
all, and robot_localization then drops it, so it is kept for records without one
(``bridge.ros2.messages``).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

from bridge.exceptions import NoiseFileError

#: The keys read from the file: Kalibr's names, in its units.
ACCEL_DENSITY = "accelerometer_noise_density"  # m/s²/√Hz
ACCEL_WALK = "accelerometer_random_walk"  # m/s³/√Hz
GYRO_DENSITY = "gyroscope_noise_density"  # rad/s/√Hz
GYRO_WALK = "gyroscope_random_walk"  # rad/s²/√Hz
UPDATE_RATE = "update_rate"  # Hz
ROSTOPIC = "rostopic"
_NUMBERS = (ACCEL_DENSITY, ACCEL_WALK, GYRO_DENSITY, GYRO_WALK, UPDATE_RATE)
#: The rate of the calculation cycles a GX3's moving average takes, Hz.
FILTER_RATE_HZ = 1000.0


def sample_variance(density: float, rate_hz: float, filter_width: int) -> float:
    """The variance of one sample, for a filter that takes the samples as white.

    σ² = N² · 1000 Hz / min(D, M) = N² · max(rate, 1000 Hz / M): the white-equivalent
    N² · rate while the decimation D is at most the width M, the samples' own variance
    N² · 1000 Hz / M once D > M leaves cycles out (the module's docstring says why).

    Args:
        density: N, the sensor's white noise density (unit/√Hz).
        rate_hz: The unit's output rate (1000 Hz / D).
        filter_width: M, its filter width (1 to 32).

    Returns:
        The variance, in the unit squared.

    Raises:
        ValueError: The rate or the width is not a positive number.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"an output rate of {rate_hz} Hz cannot give a variance")
    if not filter_width >= 1:
        raise ValueError(f"a filter width of {filter_width} cannot give a variance")
    return density**2 * max(rate_hz, FILTER_RATE_HZ / filter_width)


def white_equivalent_density(density: float, rate_hz: float, filter_width: int) -> float:
    """The density that gives ``sample_variance`` as density² · rate.

    What a tool that takes a density and a rate (Kalibr, VINS, OpenVINS) needs for the
    samples: the sensor's density while D <= M, more once D > M.

    Args:
        density: N, the sensor's white noise density.
        rate_hz: The unit's output rate.
        filter_width: M, its filter width.

    Returns:
        The density, in N's unit.

    Raises:
        ValueError: The rate or the width is not a positive number.
    """
    return math.sqrt(sample_variance(density, rate_hz, filter_width) / rate_hz)


@dataclass(frozen=True)
class ImuNoise:
    """What a Kalibr ``imu.yaml`` says of a unit's sensors.

    Attributes:
        accel_noise_density: Accelerometer white noise, m/s²/√Hz.
        accel_random_walk: Accelerometer bias random walk, m/s³/√Hz.
        gyro_noise_density: Gyro white noise, rad/s/√Hz.
        gyro_random_walk: Gyro bias random walk, rad/s²/√Hz.
        update_rate_hz: The rate the file says its measurement was made at, Hz.
        rostopic: The topic the file names, if any.
        path: The file.
        sha256: Its SHA-256, so that an output can say which file it used.
    """

    accel_noise_density: float
    accel_random_walk: float
    gyro_noise_density: float
    gyro_random_walk: float
    update_rate_hz: float
    rostopic: str | None
    path: Path
    sha256: str

    def provenance(self) -> dict[str, object]:
        """What an output records of the file: its name, digest and the values used.

        Returns:
            JSON-ready: ``file``, ``sha256`` and each key read, under Kalibr's names.
        """
        return {"file": str(self.path), "sha256": self.sha256,
                ACCEL_DENSITY: self.accel_noise_density, ACCEL_WALK: self.accel_random_walk,
                GYRO_DENSITY: self.gyro_noise_density, GYRO_WALK: self.gyro_random_walk,
                UPDATE_RATE: self.update_rate_hz, ROSTOPIC: self.rostopic}


@dataclass(frozen=True)
class ImuCovariance:
    """The three covariances of a unit's ``sensor_msgs/Imu``, row major, in ROS units.

    Attributes:
        rate_hz: The output rate the variances are for.
        filter_width: The filter width they are for.
        orientation: rad²; all 0 (unknown) unless an orientation standard deviation
            was given.
        angular_velocity: (rad/s)², the diagonal ``sample_variance``; all 0 (unknown)
            without a measured noise.
        linear_acceleration: (m/s²)², likewise.
    """

    rate_hz: float
    filter_width: int
    orientation: tuple[float, ...]
    angular_velocity: tuple[float, ...]
    linear_acceleration: tuple[float, ...]

    def as_dict(self) -> dict[str, object]:
        """The covariances as an output records them.

        Returns:
            JSON-ready: ``rate_hz``, ``filter_width`` and the three covariances, 9
            numbers each.
        """
        return {"rate_hz": self.rate_hz, "filter_width": self.filter_width,
                "orientation_covariance": list(self.orientation),
                "angular_velocity_covariance": list(self.angular_velocity),
                "linear_acceleration_covariance": list(self.linear_acceleration)}


def _diagonal(variance: float) -> tuple[float, ...]:
    return (variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance)


def imu_covariance(noise: ImuNoise | None, rate_hz: float, filter_width: int,
                   orientation_stddev: float | None = None) -> ImuCovariance:
    """The covariances of a unit's samples at its output rate and filter width.

    The same noise on each axis (Kalibr gives one density per sensor), uncorrelated:
    a diagonal. Axis signs change between the GX3's frame and ROS's, which leaves a
    diagonal as it is.

    Args:
        noise: The unit's measured noise; None: angular velocity and linear
            acceleration unknown (0).
        rate_hz: The unit's output rate (1000 Hz / decimation).
        filter_width: Its filter width M.
        orientation_stddev: The orientation's standard deviation about each axis, rad;
            None: unknown (0).

    Returns:
        The covariances.

    Raises:
        ValueError: The rate or width is not a positive number, or the standard
            deviation is negative or not finite.
    """
    sample_variance(1.0, rate_hz, filter_width)  # checks the rate and the width
    if orientation_stddev is not None and not (math.isfinite(orientation_stddev)
                                               and orientation_stddev >= 0):
        raise ValueError(f"an orientation standard deviation of {orientation_stddev} rad "
                         "cannot give a variance; give a number of radians, 0 or more")
    zero = _diagonal(0.0)
    return ImuCovariance(
        rate_hz, filter_width,
        zero if orientation_stddev is None else _diagonal(orientation_stddev**2),
        zero if noise is None else _diagonal(
            sample_variance(noise.gyro_noise_density, rate_hz, filter_width)),
        zero if noise is None else _diagonal(
            sample_variance(noise.accel_noise_density, rate_hz, filter_width)))


def _number(content: dict[object, object], key: str, path: Path) -> float:
    value = content[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise NoiseFileError(f"{path}: {key} is {value!r}, not a number; give it in Kalibr's "
                             "units (gx3 allan writes them)")
    if not (math.isfinite(value) and value >= 0) or (key != ACCEL_WALK and key != GYRO_WALK
                                                     and value == 0):
        raise NoiseFileError(f"{path}: {key} is {value}; a noise density or rate must be a "
                             "positive number (a random walk may be 0)")
    return float(value)


def read_noise(path: Path) -> ImuNoise:
    """Read a Kalibr ``imu.yaml``: only the keys above; any other key is left alone.

    Args:
        path: The file (``gx3 allan`` writes one).

    Returns:
        The unit's noise.

    Raises:
        NoiseFileError: The file cannot be read, is not YAML, lacks a key or holds a
            value that is not a positive number; the message says which.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise NoiseFileError(f"{path}: cannot read it ({exc.strerror or exc}); give the "
                             "imu.yaml that gx3 allan wrote") from None
    try:
        content = YAML(typ="safe", pure=True).load(data.decode())
    except (YAMLError, UnicodeDecodeError):
        raise NoiseFileError(f"{path}: not YAML; give the imu.yaml (Kalibr's format) "
                             "that gx3 allan wrote") from None
    if not isinstance(content, dict):
        raise NoiseFileError(f"{path}: not a Kalibr imu.yaml (a mapping of keys to values); "
                             "give the file that gx3 allan wrote")
    missing = [key for key in _NUMBERS if key not in content]
    if missing:
        raise NoiseFileError(f"{path}: lacks {', '.join(missing)}; a Kalibr imu.yaml "
                             "(gx3 allan writes one) has every one of "
                             f"{', '.join(_NUMBERS)}")
    accel, accel_walk, gyro, gyro_walk, rate = (_number(content, k, path) for k in _NUMBERS)
    topic = content.get(ROSTOPIC)
    return ImuNoise(accel, accel_walk, gyro, gyro_walk, rate,
                    rostopic=None if topic is None else str(topic), path=path,
                    sha256=hashlib.sha256(data).hexdigest())
