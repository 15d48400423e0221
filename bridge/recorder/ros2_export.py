"""Archive to a ROS 2 bag: what ``ros2 bag play`` reads, from the samples of an export.

The file is MCAP as rosbag2's MCAP storage writes it (profile ``ros2``, schema encoding
``ros2msg`` with the message definitions embedded, message encoding ``cdr``): per unit
``/<prefix>/<unit>/imu`` (``sensor_msgs/msg/Imu``) and, for records with a magnetometer,
``/<prefix>/<unit>/mag`` (``sensor_msgs/msg/MagneticField``). It is built from the rows
of :func:`bridge.recorder.export.sample_table`, so it holds exactly the samples a table
export with the same options holds, stamped with the same ``time_ns``; each message is
logged and published at its stamp, and messages are in log-time order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bridge.bus.codec import elements
from bridge.recorder.archive import LIBRARY
from bridge.recorder.export import QUANTITY_ORDER, flat_names
from bridge.recorder.mcap_writer import McapWriter
from bridge.ros2 import messages

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"


@dataclass(frozen=True)
class Ros2Written:
    """How many messages of each type a bag got."""

    imu: int
    mag: int


def quantities(table: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The export's flat columns of ``rows`` back as quantities, (n, elements) each
    (``m`` as (n, 9)), NaN where a record lacks one."""
    out = {}
    for q in QUANTITY_ORDER:
        names = flat_names(q, elements(q))
        if names[0] in table:
            out[q] = np.stack([table[name][rows] for name in names], axis=1)
    return out


def write_ros2(table: dict[str, np.ndarray], path: Path, prefix: str = "gx3") -> Ros2Written:
    """Write the samples of an export ``table`` (rows in time order) as a ROS 2 bag."""
    counts = {"imu": 0, "mag": 0}
    units = table["unit"]
    with path.open("wb") as stream:
        writer = McapWriter(stream, spill_dir=path.parent)
        try:
            writer.start(PROFILE, LIBRARY)
            schemas = {msgtype: writer.register_schema(
                msgtype, SCHEMA_ENCODING, messages.message_definition(msgtype).encode())
                for msgtype in (messages.IMU, messages.MAGNETIC_FIELD)}
            for unit in sorted(set(units.tolist())):
                rows = np.flatnonzero(units == unit)
                columns = quantities(table, rows)
                time_ns = table["time_ns"][rows]
                frame = messages.frame_id(unit, prefix)
                for name, msgtype, keep, encode in (
                        ("imu", messages.IMU, messages.has_imu, messages.imu_cdr_batch),
                        ("mag", messages.MAGNETIC_FIELD, messages.has_mag,
                         messages.mag_cdr_batch)):
                    mine = keep(columns, len(rows))
                    if not mine.any():
                        continue
                    channel = writer.register_channel(f"/{prefix}/{unit}/{name}",
                                                      MESSAGE_ENCODING, schemas[msgtype], {})
                    stamps = time_ns[mine]
                    payloads = encode(stamps, frame, {k: v[mine] for k, v in columns.items()})
                    writer.add(channel, 0, stamps, stamps, payloads)
                    counts[name] += len(payloads)
            writer.finish()
        finally:
            writer.close()
    return Ros2Written(**counts)
