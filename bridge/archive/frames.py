"""Per-unit ``foxglove.FrameTransform`` messages, so viewers show every unit's attitude in 3-D.

Foxglove and Rerun both turn this well-known schema into a transform with no plugin.
Frame names follow REP-103, prefixed with the archive's key prefix (``gx3``; slashes
become underscores) so they cannot collide with another system's:

- ``gx3_world``: the root, east-north-up, as ROS and Foxglove take any world frame;
- ``gx3_world_ned``: north-east-down, under the root (one static transform: x and y
  swapped, z turned over);
- ``gx3_<unit>_frd``: the unit's body (sensor) frame, forward-right-down, under
  ``gx3_world_ned``; the rotation is the sensor-to-earth rotation Mᵀ (a Hamilton
  quaternion x, y, z, w that turns a sensor-frame vector into NED). The ROS 2 export's
  forward-left-up body frame of the unit is ``gx3_<unit>`` (bridge/ros2/messages.py).

Units stand side by side along east, ``spacing`` metres apart, in the order they were
first seen, so their axes do not overlap on screen. A unit's frames come at most a few
times a second (``frame_picks``: on a grid of the unit's own sample times), which is
all a viewer shows, whatever the unit's rate.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Mapping

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from bridge.bus.codec import record_quantities
from bridge.bus.keys import PREFIX
from bridge.protocol.convert import euler_to_quaternion, m_to_quaternion, sensor_to_earth_xyzw
from bridge.protocol.table import DATA_CODES
from bridge.ros2.messages import frame_id

#: gx3_world -> gx3_world_ned: a half turn about (north + east) / √2 of ENU, which maps
#: NED north to ENU y, east to x, down to -z.
NED_IN_ROOT = (np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0)
#: Quantities that give a unit's attitude, in order of preference.
ATTITUDE = ("m", "quaternion", "euler")
FRAME_CLASS = FrameTransform
MARKER_CLASS = PointCloud


def _root_frame(prefix: str = PREFIX) -> str:
    """The fleet's world frame, east-north-up."""
    return frame_id("world", prefix)


def _ned_frame(prefix: str = PREFIX) -> str:
    return f"{_root_frame(prefix)}_ned"


def _body_frame(unit: str, prefix: str = PREFIX) -> str:
    """The frame id of a unit's body: forward-right-down, as the GX3's sensor axes."""
    return f"{frame_id(unit, prefix)}_frd"


def root_message(time_ns: int, prefix: str = PREFIX) -> bytes:
    """The static transform gx3_world (ENU) -> gx3_world_ned, stamped ``time_ns``."""
    x, y, z, w = NED_IN_ROOT
    return FrameTransform(timestamp=Timestamp(seconds=time_ns // 1_000_000_000,
                                              nanos=time_ns % 1_000_000_000),
                          parent_frame_id=_root_frame(prefix), child_frame_id=_ned_frame(prefix),
                          rotation=Quaternion(x=x, y=y, z=z, w=w)).SerializeToString()


def has_attitude(quantities: tuple[str, ...]) -> bool:
    """Whether a record of these quantities carries an attitude (m, quaternion or Euler)."""
    return any(q in quantities for q in ATTITUDE)


def sensor_to_earth(columns: Mapping[str, np.ndarray]) -> np.ndarray:
    """(n, 4) x, y, z, w quaternions of the sensor-to-earth rotation Mᵀ of decoded records.

    From m when the record has it (the manual's M to Q, then its Q is the Hamilton
    quaternion of Mᵀ), else from the unit's quaternion, else from Euler angles.
    """
    if "m" in columns:
        q = m_to_quaternion(columns["m"])
    elif "quaternion" in columns:
        q = np.asarray(columns["quaternion"], np.float64)
    else:
        q = euler_to_quaternion(columns["euler"])
    return sensor_to_earth_xyzw(q)


@functools.cache
def framed(code: int) -> bool:
    """Whether samples of record type ``code`` carry an attitude (and become frames)."""
    return code in DATA_CODES and has_attitude(record_quantities(code))


def frame_picks(times: np.ndarray, due: int | None,
                period: int) -> tuple[list[int], int | None]:
    """Which of a unit's attitude samples (at ``times``) become frames, and the next tick due.

    The picks are the first sample at or after each tick of a grid ``period`` apart,
    from the first sample on, so frames come exactly 1/period a second whatever the
    unit's clock drift (a grid from each pick would wait for the sample after, at
    9.9996 ms steps 20 Hz instead of 25). A tick with no sample of its own is skipped;
    time going back more than two periods (a reset) starts the grid again. Times that
    never go back (the usual case) let it jump from frame to frame, each sample's
    successor found for all at once.
    """
    if not period:
        return list(range(len(times))), due
    if len(times) and (len(times) < 2 or bool((np.diff(times) >= 0).all())):
        first = int(times[0])
        if due is None or first < due - 2 * period:
            due = first
        i = int(np.searchsorted(times, due))
        after = np.maximum(np.searchsorted(times, _next_tick(times, due, period)),
                           np.arange(1, len(times) + 1)).tolist()
        picks: list[int] = []
        while i < len(times):
            picks.append(i)
            i = after[i]
        return picks, (int(_next_tick(times[picks[-1:]], due, period)[0]) if picks else due)
    picks = []
    for i, t in enumerate(times.tolist()):
        if due is None or t < due - 2 * period:
            due = t
        if t >= due:
            picks.append(i)
            due = int(_next_tick(np.array([t]), due, period)[0])
    return picks, due


def _next_tick(times: np.ndarray, due: int, period: int) -> np.ndarray:
    """The first tick of the grid through ``due`` (``period`` apart) after each time."""
    times = np.asarray(times, np.int64)
    return due + ((times - due) // period + 1) * period


def frame_messages(unit: str, slot: int, time_ns: np.ndarray, xyzw: np.ndarray,
                   spacing: float, prefix: str = PREFIX) -> list[bytes]:
    """Serialized FrameTransforms gx3_world_ned -> gx3_<unit>_frd at ``time_ns``.

    Built for all frames at once, byte for byte what protobuf's serializer gives
    (fields in number order, zeros left out): the fields every frame shares once,
    timestamp and rotation as columns of bytes, a mask for the bytes present.
    """
    shared = FrameTransform(parent_frame_id=_ned_frame(prefix),
                            child_frame_id=_body_frame(unit, prefix),
                            translation=Vector3(x=0.0, y=slot * spacing, z=0.0))
    rotation = [part for k in range(4) for part in _double_field(k + 1, xyzw[:, k])]
    n = len(time_ns)
    return _serialized([*_stamp(time_ns), _constant(n, shared.SerializeToString()),
                        _constant(n, b"\x2a"), _length(rotation), *rotation])


def marker_messages(unit: str, time_ns: np.ndarray, prefix: str = PREFIX) -> list[bytes]:
    """Serialized PointClouds of the unit's axes in its body frame, at ``time_ns``.

    What a viewer draws for the unit: Rerun makes a 3-D view for points, none for
    transforms alone; Foxglove draws a point cloud where its frame was at its timestamp,
    so it comes with every frame.
    """
    shared = PointCloud(frame_id=_body_frame(unit, prefix),
                        pose=Pose(orientation=Quaternion(w=1.0)),
                        point_stride=_POINT.itemsize, fields=_POINT_FIELDS,
                        data=_AXES.tobytes())
    return _serialized([*_stamp(time_ns),
                        _constant(len(time_ns), shared.SerializeToString())])


#: One point: x, y, z in metres, then its colour.
_LAYOUT = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
           ("blue", "u1"), ("alpha", "u1")]
_POINT = np.dtype(_LAYOUT)
_POINT_FIELDS = [PackedElementField(name=name, offset=_POINT.fields[name][1],  # type: ignore[index]
                                    type=(PackedElementField.FLOAT32 if kind == "<f4"
                                          else PackedElementField.UINT8))
                 for name, kind in _LAYOUT]


def _axes() -> np.ndarray:
    """Dots along the body axes from the origin, so a unit's heading and which side is down show.

    x (forward) red and 0.24 m, y (right) green and z (down) blue 0.12 m.
    """
    out = np.zeros(1, _POINT)
    out[["red", "green", "blue", "alpha"]] = (255, 255, 255, 255)
    for axis, length in enumerate((0.24, 0.12, 0.12)):
        dots = np.zeros(round(length / 0.03), _POINT)
        dots["xyz"[axis]] = np.linspace(0.03, length, len(dots))
        dots[("red", "green", "blue")[axis]] = dots["alpha"] = 255
        out = np.concatenate([out, dots])
    return out


_AXES = _axes()


def _stamp(time_ns: np.ndarray) -> list[_Column]:
    """Field 1 of a Foxglove message, its google.protobuf.Timestamp, per time."""
    seconds, nanos = np.divmod(np.asarray(time_ns, np.int64), 1_000_000_000)
    stamp = [*_varint_field(1, seconds), *_varint_field(2, nanos)]
    return [_constant(len(seconds), b"\x0a"), _length(stamp), *stamp]


def _serialized(columns: list[_Column]) -> list[bytes]:
    """One message per row of ``columns``: the bytes present, row by row."""
    rows = np.concatenate([c for c, _ in columns], axis=1)
    present = np.concatenate([m for _, m in columns], axis=1)
    data = rows[present].tobytes()
    bounds = [0, *np.cumsum(present.sum(axis=1)).tolist()]
    return [data[a:b] for a, b in itertools.pairwise(bounds)]


_Column = tuple[np.ndarray, np.ndarray]  # (n, width) bytes and which of them are present


def _constant(n: int, data: bytes) -> _Column:
    row = np.frombuffer(data, np.uint8)
    return np.broadcast_to(row, (n, len(row))), np.ones((n, len(row)), bool)


def _length(parts: list[_Column]) -> _Column:
    """The one-byte length of a small embedded message made of ``parts``."""
    size = sum(m.sum(axis=1) for _, m in parts)
    return np.asarray(size, np.uint8).reshape(-1, 1), np.ones((len(size), 1), bool)


def _varint_field(number: int, values: np.ndarray) -> list[_Column]:
    """Tag and base-128 varint of an int field, left out where it is 0."""
    v = values.astype(np.int64).view(np.uint64)
    groups = (v[:, None] >> (7 * np.arange(10, dtype=np.uint64))) & np.uint64(0x7F)
    used = np.maximum(1, 10 - np.argmax((groups != 0)[:, ::-1], axis=1))
    more = np.arange(10) < (used - 1)[:, None]
    present = v != 0
    tag = np.full((len(v), 1), number << 3, np.uint8)
    return [(tag, present[:, None]),
            (groups.astype(np.uint8) | np.where(more, 0x80, 0).astype(np.uint8),
             (np.arange(10) < used[:, None]) & present[:, None])]


def _double_field(number: int, values: np.ndarray) -> list[_Column]:
    """Tag and little-endian bytes of a double field, left out where it is +0.0."""
    raw = np.ascontiguousarray(values, "<f8").view(np.uint8).reshape(-1, 8)
    present = (raw != 0).any(axis=1)[:, None]
    tag = np.full((len(raw), 1), number << 3 | 1, np.uint8)
    return [(tag, present), (raw, np.broadcast_to(present, raw.shape))]
