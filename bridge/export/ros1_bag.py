"""Archive to a ROS 1 bag: what Kalibr, allan_variance_ros and imu_utils read.

A ROS 1 bag (format 2.0, ``.bag``) written with rosbags' ROS 1 writer, Noetic's message
definitions and MD5 sums in its connections, holding the messages ``bridge.export.bags``
says a bag holds, each logged at its stamp; a topic's header ``seq`` counts its
messages from 0. A ROS 1 message is the ROS 2 message's fields without CDR's
encapsulation and alignment: the header (``seq``, the stamp as uint32 seconds and
nanoseconds, the frame id as a uint32 length and its bytes), then the float64 fields,
packed little-endian.

A bag has no metadata records. What a ROS 2 bag keeps in each of its metadata records
(``gx3.noise``: the noise file and the covariances it gave; ``gx3.mounts``: the mounts
file) goes into one latched ``std_msgs/String`` on ``/<prefix>/gx3_noise`` or
``/<prefix>/gx3_mounts``, as JSON, at the first message's stamp.

Kalibr reads a single bag, the camera's images and the IMU's samples together: another
ROS 1 bag (the camera's, recorded by ROS) can be merged in, its connections and
messages copied as they are, so the output is the one bag Kalibr needs and the camera's
file stays untouched.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.export.bags import BagWritten, bag_slices
from bridge.ros2.messages import ros_token
from bridge.ros2.noise import ImuCovariance

if TYPE_CHECKING:
    from rosbags.rosbag1 import Writer

__all__ = ["check_merge", "record_topic", "ros1_messages", "write_ros1"]

_STRING = "std_msgs/msg/String"


def ros1_messages(time_ns: npt.ArrayLike, frame: str, values: np.ndarray,
                  first: int = 0) -> list[bytes]:
    """ROS 1 bytes of one message per row: a std_msgs/Header, then the row's float64s.

    Args:
        time_ns: Each message's stamp, int ns since 1970.
        frame: The header's frame id.
        values: (n, k) float64: the message's fields after its header.
        first: The first message's ``seq``; the others count on.

    Returns:
        One message per row.

    Raises:
        ValueError: A stamp is outside ROS 1's time (uint32 seconds since 1970).
    """
    t = np.asarray(time_ns, np.int64).reshape(-1)
    name = frame.encode()
    layout = np.dtype({"names": ["seq", "sec", "nsec", "length", "frame_id", "values"],
                       "formats": ["<u4", "<u4", "<u4", "<u4", f"V{len(name)}",
                                   ("<f8", (values.shape[1],))],
                       "offsets": [0, 4, 8, 12, 16, 16 + len(name)],
                       "itemsize": 16 + len(name) + 8 * values.shape[1]})
    sec, nsec = np.divmod(t, 1_000_000_000)
    if len(t) and (sec.min() < 0 or sec.max() >= 2**32):
        raise ValueError("a time stamp is outside the range of a ROS 1 time (uint32 seconds "
                         "since 1970)")
    out = np.zeros(len(t), layout)
    out["seq"] = (first + np.arange(len(t))) & 0xFFFF_FFFF
    out["sec"], out["nsec"], out["length"] = sec, nsec, len(name)
    if name:
        out["frame_id"] = np.void(name)
    out["values"] = values
    data, size = out.tobytes(), layout.itemsize
    return [data[i : i + size] for i in range(0, len(data), size)]


def record_topic(prefix: str, name: str) -> str:
    """The latched topic of a ROS 2 bag's metadata record ``name`` (``gx3.noise``).

    Args:
        prefix: The key prefix, the first part of the topic.
        name: The record's name.

    Returns:
        ``/<prefix>/<name>``, each part a ROS name (``/gx3/gx3_noise``).
    """
    return "/" + "/".join(map(ros_token, [*prefix.split("/"), name]))


def check_merge(path: Path) -> list[str]:
    """The topics of a ROS 1 bag to merge, or a one-line refusal if it cannot be read.

    Args:
        path: The bag.

    Returns:
        Its topics.

    Raises:
        ValueError: It is missing or not a ROS 1 bag.
    """
    from rosbags.rosbag1 import Reader, ReaderError

    try:
        with Reader(path) as reader:
            return sorted({c.topic for c in reader.connections})
    except (ReaderError, OSError) as exc:
        raise ValueError(f"--merge {path}: cannot read it as a ROS 1 bag ({exc}); give the "
                         "camera's .bag as ROS 1 recorded it") from None


def _merge(writer: Writer, path: Path, taken: set[str]) -> int:
    """Copy every connection and message of the ROS 1 bag ``path``; its messages' count."""
    from rosbags.rosbag1 import Reader

    copied = 0
    with Reader(path) as reader:
        clash = sorted(taken & {c.topic for c in reader.connections})
        if clash:
            raise ValueError(f"--merge {path} already has the topic {clash[0]}, which the "
                             "export writes; merge a bag without the unit's topics")
        ours = {}
        for c in reader.connections:
            ext = c.ext
            ours[c.id] = writer.add_connection(
                c.topic, c.msgtype, msgdef=c.msgdef.data, md5sum=c.digest,
                callerid=getattr(ext, "callerid", None), latching=getattr(ext, "latching", None))
        for connection, stamp, data in reader.messages():
            writer.write(ours[connection.id], stamp, data)
            copied += 1
    return copied


def write_ros1(table: dict[str, np.ndarray], path: Path, prefix: str = "gx3", *,
               covariances: Mapping[str, ImuCovariance] | None = None,
               metadata: Mapping[str, Mapping[str, object]] | None = None,
               frames: Mapping[str, str] | None = None,
               merge: Path | None = None) -> BagWritten:
    """Write the samples of an export table as a ROS 1 bag.

    Args:
        table: A sample table (``sample_table``), rows in time order.
        path: The bag to write (a .bag file; it must not exist yet).
        prefix: The key prefix, the first part of the topics and frame ids.
        covariances: Per unit, its Imu covariances (``imu_covariance``); a unit not
            in it gets 0 (unknown).
        metadata: What a ROS 2 bag's metadata records hold, by name (``gx3.noise``,
            ``gx3.mounts``): each as JSON on its latched topic (``record_topic``).
        frames: Per unit, the unit whose frame its messages are in (a mounted unit's
            are in its reference's, ``gx3 export --mounts``); a unit not in it: its own.
        merge: Another ROS 1 bag (the camera's) whose connections and messages are
            copied in as they are; None: none.

    Returns:
        How many messages of each type the bag got.

    Raises:
        ValueError: A sample's time is outside ROS 1's time (uint32 seconds since 1970),
            or the bag to merge cannot be read or has one of the export's topics.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    counts = {"imu": 0, "mag": 0}
    writer = Writer(path)
    writer.set_compression(Writer.CompressionFormat.LZ4)
    writer.open()
    try:
        connections = {}
        for part in bag_slices(table, prefix, covariances or {}, frames or {}):
            if part.topic not in connections:
                connections[part.topic] = writer.add_connection(part.topic, part.msgtype,
                                                                typestore=store)
            connection = connections[part.topic]
            for stamp, data in zip(part.time_ns.tolist(),
                                   ros1_messages(part.time_ns, part.frame, part.values,
                                                 part.first), strict=True):
                writer.write(connection, stamp, data)
            counts[part.leaf] += len(part.time_ns)
        stamps = table["time_ns"]
        for name, content in (metadata or {}).items() if len(stamps) else ():
            text = json.dumps(dict(content), sort_keys=True).encode()
            latched = writer.add_connection(record_topic(prefix, name), _STRING,
                                            typestore=store, latching=1)
            writer.write(latched, int(stamps.min()), struct.pack("<I", len(text)) + text)
        merged = 0 if merge is None else _merge(writer, merge, set(connections))
    finally:
        writer.close()
    return BagWritten(**counts, merged=merged)
