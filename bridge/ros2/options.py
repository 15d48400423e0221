"""What a live bridge's ROS 2 topics are asked for: the domain, the distribution, the noise.

One value that ``gx3 bridge --ros2`` hands through the unit's bridge to its topics
(``bridge.ros2.rmw.UnitTopics``), checked where it is made, without importing Zenoh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bridge.ros2.messages import DEFAULT_DISTRO, check_distro
from bridge.ros2.noise import ImuNoise


@dataclass(frozen=True)
class Ros2Options:
    """A unit's ROS 2 topics, as asked for.

    Attributes:
        domain: The ROS domain id (``ROS_DOMAIN_ID``), 0 to 232.
        distro: The distribution of the subscribers' rmw_zenoh: ``jazzy`` or ``humble``.
        noise: The unit's measured noise (``read_noise``), for the Imu's angular
            velocity and linear acceleration covariances; None: they stay 0 (unknown).
        orientation_stddev: The orientation's standard deviation about each axis, rad,
            for the orientation covariance of the Imu that carry one; None: it stays 0
            (unknown).

    Raises:
        ValueError: The distribution is not one of ``DISTROS``, or the standard deviation
            is negative.
    """

    domain: int = 0
    distro: str = DEFAULT_DISTRO
    noise: ImuNoise | None = None
    orientation_stddev: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "distro", check_distro(self.distro))
        if self.orientation_stddev is not None and not (
                math.isfinite(self.orientation_stddev) and self.orientation_stddev >= 0):
            raise ValueError(f"{self.orientation_stddev} rad is not a standard deviation; "
                             "give the orientation's in radians, 0 or more")
