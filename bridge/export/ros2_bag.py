"""Archive to a ROS 2 bag: what ``ros2 bag play`` reads, from the samples of an export.

The file is MCAP as rosbag2's MCAP storage writes it (profile ``ros2``, schema encoding
``ros2msg`` with the message definitions embedded, message encoding ``cdr``), holding
the messages ``bridge.export.bags`` says a bag holds; each message is logged and
published at its stamp, and messages are in log-time order.

With a unit's measured noise its Imu messages carry covariances (``bridge.ros2.noise``)
and the bag a ``gx3.noise`` metadata record of the file they came from. Humble's and
Jazzy's rosbag2 read the same file: the message definitions are the same text in both
distributions, and the ros2 profile asks nothing of either that the other lacks.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from bridge.archive.mcap_writer import McapWriter
from bridge.archive.writer import LIBRARY
from bridge.export.bags import BagWritten, bag_slices
from bridge.ros2 import messages
from bridge.ros2.noise import ImuCovariance

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: Channel metadata the ros2 profile requires: the publishers' QoS profiles as rosbag2's
#: YAML; none recorded (an empty list), so playback uses its defaults.
CHANNEL_METADATA = {"offered_qos_profiles": "[]"}


#: A ROS 2 bag's message counts (the name it had before ROS 1 bags came).
Ros2Written = BagWritten


def write_ros2(table: dict[str, np.ndarray], path: Path, prefix: str = "gx3", *,
               distro: str = messages.DEFAULT_DISTRO,
               covariances: Mapping[str, ImuCovariance] | None = None,
               metadata: Mapping[str, Mapping[str, str]] | None = None,
               frames: Mapping[str, str] | None = None) -> BagWritten:
    """Write the samples of an export table as a ROS 2 bag.

    Args:
        table: A sample table (``sample_table``), rows in time order.
        path: The bag to write (an MCAP file).
        prefix: The key prefix, the first part of the topics and frame ids.
        distro: The ROS 2 distribution whose message definitions the bag embeds.
        covariances: Per unit, its Imu covariances (``imu_covariance``); a unit not
            in it gets 0 (unknown).
        metadata: MCAP metadata records to add, by name (``gx3.noise``).
        frames: Per unit, the unit whose frame its messages are in (a mounted unit's
            are in its reference's, ``gx3 export --mounts``); a unit not in it: its own.

    Returns:
        How many messages of each type the bag got.

    Raises:
        ValueError: A sample's time is outside what a ROS time stamp holds (int32
            seconds since 1970), or the distribution is not one of ``DISTROS``.
    """
    counts = {"imu": 0, "mag": 0}
    with path.open("wb") as stream:
        writer = McapWriter(stream, spill_dir=path.parent)
        try:
            writer.start(PROFILE, LIBRARY)
            schemas = {msgtype: writer.register_schema(
                msgtype, SCHEMA_ENCODING,
                messages.message_definition(msgtype, distro).encode())
                for msgtype in (messages.IMU, messages.MAGNETIC_FIELD)}
            channels: dict[str, int] = {}  # topic -> channel id
            for part in bag_slices(table, prefix, covariances or {}, frames or {}):
                if part.topic not in channels:
                    channels[part.topic] = writer.register_channel(
                        part.topic, MESSAGE_ENCODING, schemas[part.msgtype], CHANNEL_METADATA)
                payloads = messages.cdr_messages(part.time_ns, part.frame, part.values)
                writer.add(channels[part.topic], part.first, part.time_ns, part.time_ns,
                           payloads)
                counts[part.leaf] += len(payloads)
            for name, data in (metadata or {}).items():
                writer.add_metadata(name, dict(data))
            writer.finish()
        finally:
            writer.close()
    return BagWritten(**counts)
