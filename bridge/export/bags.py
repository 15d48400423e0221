"""What a ROS bag of an export's samples holds, for the ROS 2 and the ROS 1 bag alike.

Per unit ``/<prefix>/<unit>/imu`` (``sensor_msgs/Imu``) and, for records with a
magnetometer, ``/<prefix>/<unit>/mag`` (``sensor_msgs/MagneticField``), in the frame
``bridge.ros2.messages`` names (a mounted unit's: its reference's), the values in
REP-103 frames and SI units. The messages come from the rows of
:func:`bridge.export.tables.sample_table`, so a bag holds exactly the samples a table
export with the same options holds, stamped with the same ``time_ns``; they are handed
out a slice of samples at a time (``SLICE``), as values, and each bag format encodes
them its own way.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from bridge.bus.codec import elements
from bridge.export.describe import QUANTITY_ORDER, flat_names
from bridge.ros2 import messages
from bridge.ros2.noise import ImuCovariance

__all__ = ["SLICE", "BagSlice", "BagWritten", "bag_slices"]

#: Samples taken at a time: the messages wait in the writer, not as Python objects.
SLICE = 1 << 16
_Keep = Callable[[Mapping[str, np.ndarray], int], np.ndarray]
_Values = Callable[[Mapping[str, np.ndarray], int, ImuCovariance | None], np.ndarray]


def _mag_values(columns: Mapping[str, np.ndarray], n: int,
                covariance: ImuCovariance | None) -> np.ndarray:
    """MagneticField values: the unit's Imu covariances are not theirs."""
    return messages.mag_values(columns, n)


#: Topic name, message type, which records get one, and their values.
TOPICS: tuple[tuple[str, str, _Keep, _Values], ...] = (
    ("imu", messages.IMU, messages.has_imu, messages.imu_values),
    ("mag", messages.MAGNETIC_FIELD, messages.has_mag, _mag_values))


@dataclass(frozen=True)
class BagWritten:
    """How many messages of each type a bag got.

    Attributes:
        imu: Imu messages.
        mag: MagneticField messages.
        merged: Messages copied from another bag (a ROS 1 bag's ``merge``).
    """

    imu: int
    mag: int
    merged: int = 0


@dataclass(frozen=True)
class BagSlice:
    """Consecutive messages of one unit's topic.

    Attributes:
        unit: The unit.
        leaf: The topic's last part: ``imu`` or ``mag``.
        msgtype: The message type (``sensor_msgs/msg/Imu``).
        topic: The ROS topic.
        frame: The header's frame id.
        time_ns: Each message's stamp, int64 ns since 1970.
        values: (n, k) float64: each message's fields after its header.
        first: The topic's messages before these (a ROS 1 header's seq).
    """

    unit: str
    leaf: str
    msgtype: str
    topic: str
    frame: str
    time_ns: np.ndarray
    values: np.ndarray
    first: int


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


def bag_slices(table: dict[str, np.ndarray], prefix: str,
               covariances: Mapping[str, ImuCovariance],
               frames: Mapping[str, str]) -> Iterator[BagSlice]:
    """The messages a bag of the table holds: unit by unit, ``SLICE`` samples at a time.

    Args:
        table: A sample table (``sample_table``), rows in time order.
        prefix: The key prefix, the first part of the topics and frame ids.
        covariances: Per unit, its Imu covariances (``imu_covariance``); a unit not in
            it gets 0 (unknown).
        frames: Per unit, the unit whose frame its messages are in (a mounted unit's
            are in its reference's, ``gx3 export --mounts``); a unit not in it: its own.

    Yields:
        The messages of one topic from one slice of a unit's samples, in time order
        within the topic.
    """
    units = table["unit"]
    sent: dict[tuple[str, str], int] = {}
    for unit in sorted(set(units.tolist())):
        unit_rows = np.flatnonzero(units == unit)
        frame = messages.frame_id(frames.get(unit, unit), prefix)
        for at in range(0, len(unit_rows), SLICE):
            rows = unit_rows[at : at + SLICE]
            columns = _quantities(table, rows)
            for leaf, msgtype, keep, values in TOPICS:
                mine = keep(columns, len(rows))
                if not mine.any():
                    continue
                count = int(mine.sum())
                yield BagSlice(unit, leaf, msgtype, messages.ros_topic(prefix, unit, leaf),
                               frame, table["time_ns"][rows][mine],
                               values({k: v[mine] for k, v in columns.items()}, count,
                                      covariances.get(unit)),
                               sent.get((unit, leaf), 0))
                sent[unit, leaf] = sent.get((unit, leaf), 0) + count
