"""ROS 2 messages of GX3 samples, shared by the archive export and live publishing.

``bridge.ros2.messages`` says once what a GX3 sample means to ROS (REP-103 and REP-145
frames, SI units, ``sensor_msgs/msg/Imu`` and ``MagneticField`` in CDR);
``bridge.ros2.rmw`` puts them on Zenoh the way ``rmw_zenoh_cpp`` does (Jazzy's or
Humble's), so that ROS 2 nodes see a bridge's units as topics; ``bridge.ros2.noise``
reads a unit's measured noise (Kalibr's ``imu.yaml``) and gives the Imu covariances.
How they fit in: ``docs/design/architecture.md``.

The Zenoh side (``UnitTopics``, ``Ros2Node``, ``Ros2Publisher``, ``Qos``) and the
rosbags type stores (``DISTROS``) are imported on first use, so that the archive export
needs no Zenoh, and the archive and a live bridge without ROS 2 topics no rosbags.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported
from bridge.ros2.messages import (
    IMU,
    MAGNETIC_FIELD,
    check_distro,
    frame_id,
    imu_cdr,
    imu_cdr_batch,
    mag_cdr_batch,
    message_definition,
    ros_topic,
    type_hash,
)
from bridge.ros2.noise import ImuCovariance, ImuNoise, imu_covariance, read_noise
from bridge.ros2.options import Ros2Options

if TYPE_CHECKING:
    from bridge.ros2.messages import DISTROS
    from bridge.ros2.rmw import Qos, Ros2Node, Ros2Publisher, UnitTopics

__all__ = [
    "DISTROS",
    "IMU",
    "MAGNETIC_FIELD",
    "ImuCovariance",
    "ImuNoise",
    "Qos",
    "Ros2Node",
    "Ros2Options",
    "Ros2Publisher",
    "UnitTopics",
    "check_distro",
    "frame_id",
    "imu_cdr",
    "imu_cdr_batch",
    "imu_covariance",
    "mag_cdr_batch",
    "message_definition",
    "read_noise",
    "ros_topic",
    "type_hash",
]

#: Names whose module imports Zenoh (or, DISTROS, rosbags), imported on first use.
_ON_FIRST_USE = {**{name: "bridge.ros2.rmw" for name in ("Qos", "Ros2Node", "Ros2Publisher",
                                                         "UnitTopics")},
                 "DISTROS": "bridge.ros2.messages"}


def __getattr__(name: str) -> object:
    return imported(__name__, _ON_FIRST_USE, name)
