"""Per-unit ``foxglove.FrameTransform`` messages, so viewers show every unit's attitude in 3-D.

Foxglove and Rerun (``rerun archive.mcap``) both turn this well-known schema into a
transform with no plugin. The parent frame is ``world``, north-east-down; the child
frame is the unit name; the rotation is the sensor-to-earth rotation Mᵀ (a Hamilton
quaternion x, y, z, w that turns a sensor-frame vector into NED). Units stand side by
side along east, ``spacing`` metres apart, in the order they were first seen, so their
axes do not overlap on screen.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from bridge.protocol.convert import euler_to_quaternion, m_to_quaternion, sensor_to_earth_xyzw

WORLD = "world"
#: Quantities that give a unit's attitude, in order of preference.
ATTITUDE = ("m", "quaternion", "euler")
FRAME_CLASS = FrameTransform


def has_attitude(quantities: tuple[str, ...]) -> bool:
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


def frame_messages(unit: str, slot: int, time_ns: np.ndarray, xyzw: np.ndarray,
                   spacing: float) -> list[bytes]:
    """Serialized FrameTransforms of ``unit`` (world -> unit) at ``time_ns``."""
    out: list[bytes] = []
    translation = Vector3(x=0.0, y=slot * spacing, z=0.0)
    for t, (x, y, z, w) in zip(time_ns.tolist(), xyzw.tolist(), strict=True):
        msg = FrameTransform(timestamp=Timestamp(seconds=t // 1_000_000_000,
                                                 nanos=t % 1_000_000_000),
                             parent_frame_id=WORLD, child_frame_id=unit,
                             translation=translation,
                             rotation=Quaternion(x=x, y=y, z=z, w=w))
        out.append(msg.SerializeToString())
    return out
