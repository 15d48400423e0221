"""Archive to a ROS 2 bag: what ``ros2 bag play`` reads, from the samples of an export.

The file is MCAP as rosbag2's MCAP storage writes it (profile ``ros2``, schema encoding
``ros2msg`` with the message definitions embedded, message encoding ``cdr``): per unit
``/<prefix>/<unit>/imu`` (``sensor_msgs/msg/Imu``) and, for records with a magnetometer,
``/<prefix>/<unit>/mag`` (``sensor_msgs/msg/MagneticField``). It is built from the rows
of :func:`bridge.export.tables.sample_table`, so it holds exactly the samples a table
export with the same options holds, stamped with the same ``time_ns``; each message is
logged and published at its stamp, and messages are in log-time order.

With a unit's measured noise its Imu messages carry covariances (``bridge.ros2.noise``)
and the bag a ``gx3.noise`` metadata record of the file they came from. Humble's and
Jazzy's rosbag2 read the same file: the message definitions are the same text in both
distributions, and the ros2 profile asks nothing of either that the other lacks.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from bridge.archive.mcap_writer import McapWriter
from bridge.archive.writer import LIBRARY
from bridge.bus.codec import elements
from bridge.export.describe import QUANTITY_ORDER, flat_names
from bridge.ros2 import messages
from bridge.ros2.noise import ImuCovariance

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: Channel metadata the ros2 profile requires: the publishers' QoS profiles as rosbag2's
#: YAML; none recorded (an empty list), so playback uses its defaults.
CHANNEL_METADATA = {"offered_qos_profiles": "[]"}
#: Samples encoded at a time: the messages wait in the writer (spilled to disk when many),
#: not as Python objects.
SLICE = 1 << 16
_Keep = Callable[[Mapping[str, np.ndarray], int], np.ndarray]
_Encode = Callable[[np.ndarray, str, Mapping[str, np.ndarray], ImuCovariance | None],
                   list[bytes]]


def _mag_cdr_batch(time_ns: npt.ArrayLike, frame: str, columns: Mapping[str, np.ndarray],
                   covariance: ImuCovariance | None) -> list[bytes]:
    """MagneticField messages: the unit's Imu covariances are not theirs."""
    return messages.mag_cdr_batch(time_ns, frame, columns)


#: Topic name, message type, which records get one, and how they are encoded.
_TOPICS: tuple[tuple[str, str, _Keep, _Encode], ...] = (
    ("imu", messages.IMU, messages.has_imu, messages.imu_cdr_batch),
    ("mag", messages.MAGNETIC_FIELD, messages.has_mag, _mag_cdr_batch))


@dataclass(frozen=True)
class Ros2Written:
    """How many messages of each type a bag got."""

    imu: int
    mag: int


def _quantities(table: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The export's flat columns of ``rows`` back as quantities, (n, elements) each.

    ``m`` comes as (n, 9); NaN where a record lacks a quantity.
    """
    out = {}
    for q in QUANTITY_ORDER:
        names = flat_names(q, elements(q))
        if names[0] in table:
            out[q] = np.stack([table[name][rows] for name in names], axis=1)
    return out


def write_ros2(table: dict[str, np.ndarray], path: Path, prefix: str = "gx3", *,
               distro: str = messages.DEFAULT_DISTRO,
               covariances: Mapping[str, ImuCovariance] | None = None,
               metadata: Mapping[str, Mapping[str, str]] | None = None,
               frames: Mapping[str, str] | None = None) -> Ros2Written:
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
    covariances = covariances or {}
    counts = {"imu": 0, "mag": 0}
    units = table["unit"]
    with path.open("wb") as stream:
        writer = McapWriter(stream, spill_dir=path.parent)
        try:
            writer.start(PROFILE, LIBRARY)
            schemas = {msgtype: writer.register_schema(
                msgtype, SCHEMA_ENCODING,
                messages.message_definition(msgtype, distro).encode())
                for msgtype in (messages.IMU, messages.MAGNETIC_FIELD)}
            channels: dict[tuple[str, str], int] = {}  # (unit, topic name) -> channel id
            sent: dict[tuple[str, str], int] = {}  # messages, the next one's sequence number
            for unit in sorted(set(units.tolist())):
                unit_rows = np.flatnonzero(units == unit)
                frame = messages.frame_id((frames or {}).get(unit, unit), prefix)
                for at in range(0, len(unit_rows), SLICE):
                    rows = unit_rows[at : at + SLICE]
                    columns = _quantities(table, rows)
                    for name, msgtype, keep, encode in _TOPICS:
                        mine = keep(columns, len(rows))
                        if not mine.any():
                            continue
                        if (unit, name) not in channels:
                            channels[unit, name] = writer.register_channel(
                                messages.ros_topic(prefix, unit, name), MESSAGE_ENCODING,
                                schemas[msgtype], CHANNEL_METADATA)
                            sent[unit, name] = 0
                        stamps = table["time_ns"][rows][mine]
                        payloads = encode(stamps, frame,
                                          {k: v[mine] for k, v in columns.items()},
                                          covariances.get(unit))
                        writer.add(channels[unit, name], sent[unit, name], stamps, stamps,
                                   payloads)
                        sent[unit, name] += len(payloads)
                        counts[name] += len(payloads)
            for name, data in (metadata or {}).items():
                writer.add_metadata(name, dict(data))
            writer.finish()
        finally:
            writer.close()
    return Ros2Written(**counts)
