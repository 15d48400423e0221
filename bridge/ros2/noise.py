"""A unit's measured sensor noise (Kalibr's ``imu.yaml``), and the covariances it gives.

``gx3 allan`` (or Kalibr's own tools) writes the white-noise densities and bias random
walks of a unit's accelerometers and gyros as Kalibr's ``imu.yaml``. A ROS consumer wants
the variance of one sample instead: for white noise of density N sampled at ``rate``
Hz, σ² = N² · rate (the density times the square root of the sample rate is the
standard deviation of one sample). The rate is the unit's actual output rate (1000 Hz /
decimation, from its Info), not the file's ``update_rate``: the samples the messages
carry come at the unit's rate, and a file measured at another rate still gives the
density, which does not depend on the rate.

The orientation has no such measurement: the 3DM-GX3 manual states no attitude accuracy
for any model, so its covariance keeps element 0 at -1 (REP-145: no estimate to
trust) rather than a number nobody measured.
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
#: A covariance whose quantity has no estimate to trust (sensor_msgs/Imu, REP-145).
NO_ESTIMATE = (-1.0, *(0.0,) * 8)


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
        orientation: rad²; element 0 -1: no estimate to trust.
        angular_velocity: (rad/s)², the diagonal σ² = N² · rate.
        linear_acceleration: (m/s²)², the diagonal σ² = N² · rate.
    """

    rate_hz: float
    orientation: tuple[float, ...]
    angular_velocity: tuple[float, ...]
    linear_acceleration: tuple[float, ...]

    def as_dict(self) -> dict[str, object]:
        """The covariances as an output records them.

        Returns:
            JSON-ready: ``rate_hz`` and the three covariances, 9 numbers each.
        """
        return {"rate_hz": self.rate_hz, "orientation_covariance": list(self.orientation),
                "angular_velocity_covariance": list(self.angular_velocity),
                "linear_acceleration_covariance": list(self.linear_acceleration)}


def _diagonal(variance: float) -> tuple[float, ...]:
    return (variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance)


def imu_covariance(noise: ImuNoise, rate_hz: float) -> ImuCovariance:
    """The covariances of a unit's samples at its output rate.

    The same noise on each axis (Kalibr gives one density per sensor), uncorrelated:
    a diagonal. Axis signs change between the GX3's frame and ROS's, which leaves a
    diagonal as it is.

    Args:
        noise: The unit's measured noise.
        rate_hz: The unit's output rate (1000 Hz / decimation).

    Returns:
        The covariances.

    Raises:
        ValueError: The rate is not a positive number.
    """
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"an output rate of {rate_hz} Hz cannot give a variance")
    return ImuCovariance(rate_hz, NO_ESTIMATE,
                         _diagonal(noise.gyro_noise_density ** 2 * rate_hz),
                         _diagonal(noise.accel_noise_density ** 2 * rate_hz))


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
