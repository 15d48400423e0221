"""GX3 samples as ROS 2 ``sensor_msgs/msg/Imu`` and ``sensor_msgs/msg/MagneticField``.

One definition of what a GX3 sample means to ROS, for the archive export and for live
publishing alike:

- Frames follow REP-103 and REP-145: the GX3's body frame is forward-right-down and its
  earth frame north-east-down; ROS wants body forward-left-up (FLU) and world east-north-up
  (ENU). Vectors in the body frame keep x and negate y and z; the orientation is the
  rotation that turns a body (FLU) vector into the world (ENU) frame, as x, y, z, w.
- Linear acceleration is specific force in m/s² (the GX3 reports g; a level unit at rest
  reads -1 g on its down axis, so +9.81 m/s² on z up), angular velocity rad/s, the
  magnetic field tesla (the GX3 reports gauss).
- A quantity a record does not carry (a NaN row, or a column that is absent) is marked
  the way sensor_msgs documents it: element 0 of its covariance is -1, its value the
  message's default. A quantity it carries has the covariance ``bridge.ros2.noise``
  gives (angular velocity and linear acceleration from a measured noise, the
  orientation from a standard deviation given), or else all 0, which sensor_msgs/Imu
  defines as "covariance unknown" (REP-145).

Messages are CDR (little-endian, XCDR1, the encapsulation rosbag2 and rmw use), built for
a whole batch at once with NumPy: every message of one frame id has the same layout, so
a structured array writes all of them in one pass. The message definitions and type
hashes come from the ``rosbags`` type store of the ROS 2 distribution asked for (Humble's
and Jazzy's definitions of these messages are the same text, and so are their hashes);
rosbags is imported when they are first asked for, so that what uses only the rest (the
archive's frames, a live bridge without ROS 2 topics) never loads it.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.protocol.convert import (
    STANDARD_GRAVITY,
    euler_to_m,
    m_to_quaternion,
    quaternion_to_m,
    sensor_to_earth_xyzw,
)
from bridge.ros2.noise import ImuCovariance

if TYPE_CHECKING:
    from rosbags.typesys import Stores
    from rosbags.typesys.store import Typestore

    #: The rosbags type store of each ROS 2 distribution spoken, by name (imported on
    #: first use, by ``__getattr__``).
    DISTROS: dict[str, Stores]

#: The ROS 2 distributions spoken, whose message definitions and type hashes are used.
DISTRO_NAMES = ("humble", "jazzy")
#: The distribution spoken unless another is asked for.
DEFAULT_DISTRO = "jazzy"
IMU = "sensor_msgs/msg/Imu"
MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
TESLA_PER_GAUSS = 1e-4
#: Body FRD -> FLU (its own inverse), and earth NED -> world ENU.
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: Quantities that give a record's attitude, in order of preference.
ATTITUDE = ("m", "quaternion", "euler")
#: Magnetometer quantities, in order of preference (stab_mag: the gyro-stabilised field).
MAGNETOMETER = ("mag", "stab_mag")
#: Little-endian CDR encapsulation header (representation id CDR_LE, no options).
_ENCAPSULATION = b"\x00\x01\x00\x00"


def check_distro(distro: str) -> str:
    """A ROS 2 distribution's name as the others take it, or a one-line refusal.

    Args:
        distro: ``humble`` or ``jazzy``, in any case.

    Returns:
        The name, lower case.

    Raises:
        ValueError: Another name.
    """
    name = distro.lower()
    if name not in DISTRO_NAMES:
        raise ValueError(f"ROS 2 distribution {distro!r}: give {' or '.join(DISTRO_NAMES)}")
    return name


@functools.cache
def _stores() -> dict[str, Stores]:
    """``DISTROS``: rosbags, imported now."""
    from rosbags.typesys import Stores

    return {"humble": Stores.ROS2_HUMBLE, "jazzy": Stores.ROS2_JAZZY}


def __getattr__(name: str) -> object:
    if name == "DISTROS":
        return _stores()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@functools.cache
def _typestore(distro: str = DEFAULT_DISTRO) -> Typestore:
    from rosbags.typesys import get_typestore

    return get_typestore(_stores()[check_distro(distro)])


def message_definition(msgtype: str, distro: str = DEFAULT_DISTRO) -> str:
    """The ``ros2msg`` text rosbag2 embeds as an MCAP schema.

    The message, then each type it uses after a line of ``=`` and ``MSG: <type>``.

    Args:
        msgtype: The message type, e.g. ``sensor_msgs/msg/Imu``.
        distro: The ROS 2 distribution whose definition it is.

    Returns:
        The definition.

    Raises:
        ValueError: The distribution is not one of ``DISTROS``.
    """
    return _typestore(distro).generate_msgdef(msgtype, ros_version=2)[0]


def type_hash(msgtype: str) -> str:
    """The message's RIHS01 type hash (REP-2011; Jazzy's rmw_zenoh puts it in its keys).

    Args:
        msgtype: The message type, e.g. ``sensor_msgs/msg/Imu``.

    Returns:
        The hash, e.g. ``RIHS01_7d9a…`` for Imu.
    """
    return _typestore().hash_rihs01(msgtype)


_NOT_ROS = re.compile(r"[^A-Za-z0-9_]+")


def ros_token(name: str) -> str:
    """A unit name or key prefix as one ROS name token.

    Letters, digits, single '_', not starting with a digit: ``imu-1`` -> ``imu_1``,
    ``6234.1`` -> ``u6234_1``.
    """
    token = _NOT_ROS.sub("_", name).strip("_")
    token = re.sub("_+", "_", token) or "unit"
    return f"u{token}" if token[0].isdigit() else token


def ros_topic(prefix: str, unit: str, leaf: str) -> str:
    """A unit's ROS topic: its Zenoh key, the chunks made ROS name tokens.

    Args:
        prefix: The key prefix (``gx3``).
        unit: The unit's name.
        leaf: The topic's last part (``imu``, ``mag``).

    Returns:
        The topic, e.g. ``/gx3/imu1/imu``.
    """
    return "/" + "/".join(ros_token(c) for c in (*prefix.split("/"), unit, leaf))


def frame_id(unit: str, prefix: str = "gx3") -> str:
    """A unit's body frame: ``gx3_<unit>``, prefixed so it cannot collide with another system's.

    Args:
        unit: The unit's name.
        prefix: The key prefix; its slashes become underscores.

    Returns:
        The frame id.
    """
    return f"{prefix.replace('/', '_')}_{unit}"


def _body_flu(frd: npt.ArrayLike) -> np.ndarray:
    """(..., 3) vectors in the GX3 body frame (forward-right-down) -> forward-left-up."""
    out: np.ndarray = np.asarray(frd, np.float64) * np.array([1.0, -1.0, -1.0])
    return out


def _earth_to_sensor(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """(n, 3, 3) M (earth NED -> sensor FRD) of n records.

    Each from m, the quaternion or the Euler angles, whichever it holds first in that
    order; NaN where it holds none.
    """
    as_m: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        "m": lambda v: v.reshape(n, 3, 3), "quaternion": quaternion_to_m, "euler": euler_to_m}
    out = np.full((n, 3, 3), np.nan)
    for name in ATTITUDE:
        if name in columns:
            m = as_m[name](np.asarray(columns[name], np.float64).reshape(n, -1))
            fill = np.isnan(out[:, 0, 0]) & np.isfinite(m).all(axis=(1, 2))
            out[fill] = m[fill]
    return out


def _orientation_xyzw(m: npt.ArrayLike) -> np.ndarray:
    """(..., 3, 3) M -> (..., 4) x, y, z, w: the rotation from body FLU to world ENU.

    GX3 body-to-earth is Mᵀ; in ROS frames that is NED_TO_ENU · Mᵀ · FRD_TO_FLU, whose
    transpose FRD_TO_FLU · M · ENU_TO_NED is an "M" the manual's M-to-Q turns into the
    Hamilton quaternion of the ROS rotation.
    """
    ros_m = FRD_TO_FLU @ np.asarray(m, np.float64) @ NED_TO_ENU.T
    return sensor_to_earth_xyzw(m_to_quaternion(ros_m))


def _rows(columns: Mapping[str, np.ndarray], names: tuple[str, ...], n: int,
          width: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, width) float64 values, each row from the first of ``names`` that it holds (finite).

    Also which rows hold one; zeros where none.
    """
    values, present = np.zeros((n, width)), np.zeros(n, bool)
    for name in names:
        if name in columns:
            mine = np.asarray(columns[name], np.float64).reshape(n, width)
            fill = ~present & np.isfinite(mine).all(axis=1)
            values[fill] = mine[fill]
            present |= fill
    return values, present


def _stamp_layout(frame: str, doubles: int) -> np.dtype:
    """The CDR layout of a message: a std_msgs/Header of ``frame``, then ``doubles`` float64.

    The doubles are aligned to 8 from the end of the encapsulation.
    """
    name = frame.encode() + b"\x00"
    body = 12 + len(name)
    first = -(-body // 8) * 8
    return np.dtype({
        "names": ["encapsulation", "sec", "nanosec", "length", "frame_id", "doubles"],
        "formats": ["V4", "<i4", "<u4", "<u4", f"V{len(name)}", ("<f8", (doubles,))],
        "offsets": [0, 4, 8, 12, 16, 4 + first],
        "itemsize": 4 + first + 8 * doubles,
    })


def cdr_messages(time_ns: npt.ArrayLike, frame: str, doubles: np.ndarray) -> list[bytes]:
    """CDR bytes of one message per row: a std_msgs/Header stamped ``time_ns``, then the row.

    Args:
        time_ns: Each message's stamp, int ns since 1970.
        frame: The header's frame id.
        doubles: (n, k) float64: the message's fields after its header.

    Returns:
        One message per row.

    Raises:
        ValueError: A stamp is outside the range of builtin_interfaces/Time.
    """
    t = np.asarray(time_ns, np.int64).reshape(-1)
    layout = _stamp_layout(frame, doubles.shape[1])
    out = np.zeros(len(t), layout)
    name = frame.encode() + b"\x00"
    out["encapsulation"] = np.void(_ENCAPSULATION)
    sec, nanosec = np.divmod(t, 1_000_000_000)
    if len(t) and (sec.min() < -(2**31) or sec.max() >= 2**31):
        raise ValueError("a time stamp is outside the range of builtin_interfaces/Time "
                         "(int32 seconds since 1970)")
    out["sec"], out["nanosec"] = sec, nanosec
    out["length"] = len(name)
    out["frame_id"] = np.void(name)
    out["doubles"] = doubles
    size = layout.itemsize
    data = out.tobytes()
    return [data[i : i + size] for i in range(0, len(data), size)]


def imu_values(columns: Mapping[str, np.ndarray], n: int,
               covariance: ImuCovariance | None = None) -> np.ndarray:
    """The fields of n Imu messages after their header, in ROS frames and units.

    What ROS 1 and ROS 2 messages alike carry, in the messages' order.

    Args:
        columns: The records' quantities as the GX3 gives them (``accel`` g,
            ``ang_rate`` rad/s, ``m`` / ``quaternion`` / ``euler``), (n, ...) each; NaN
            rows are absent.
        n: How many records.
        covariance: The unit's covariances for the quantities a record carries; None:
            all 0 (unknown).

    Returns:
        (n, 37) float64: orientation x y z w and its covariance, angular velocity and
        its covariance, linear acceleration and its covariance; element 0 of a
        covariance -1 where the record lacks the quantity.
    """
    out = np.zeros((n, 37))
    m = _earth_to_sensor(columns, n)
    has = np.isfinite(m).all(axis=(1, 2))
    out[has, 0:4] = _orientation_xyzw(m[has])
    out[~has, 3] = 1.0  # geometry_msgs/Quaternion's default: the identity
    rate, has_rate = _rows(columns, ("ang_rate",), n, 3)
    out[has_rate, 13:16] = _body_flu(rate[has_rate])
    accel, has_accel = _rows(columns, ("accel",), n, 3)
    out[has_accel, 25:28] = _body_flu(accel[has_accel]) * STANDARD_GRAVITY
    if covariance is not None:
        out[has, 4:13] = covariance.orientation
        out[has_rate, 16:25] = covariance.angular_velocity
        out[has_accel, 28:37] = covariance.linear_acceleration
    out[~has, 4] = out[~has_rate, 16] = out[~has_accel, 28] = -1.0
    return out


def has_imu(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Which of n records carry anything an Imu message holds (attitude, rate, accel)."""
    found = np.zeros(n, bool)
    for name in (*ATTITUDE, "ang_rate", "accel"):
        if name in columns:
            found |= np.isfinite(np.asarray(columns[name], np.float64).reshape(n, -1)).all(axis=1)
    return found


def has_mag(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """Which of n records carry a magnetic field."""
    return _rows(columns, MAGNETOMETER, n, 3)[1]


def imu_cdr_batch(time_ns: npt.ArrayLike, frame: str, columns: Mapping[str, np.ndarray],
                  covariance: ImuCovariance | None = None) -> list[bytes]:
    """CDR ``sensor_msgs/msg/Imu`` of each record, in ROS frames and units.

    A quantity a record lacks (a NaN row, or an absent column) is marked by element 0
    of its covariance, -1.

    Args:
        time_ns: Each record's stamp, int ns since 1970.
        frame: The frame id (``frame_id``).
        columns: The records' quantities as the GX3 gives them (``accel`` g,
            ``ang_rate`` rad/s, ``m`` / ``quaternion`` / ``euler``), (n, ...) each.
        covariance: The unit's covariances (``imu_covariance``) for the quantities a
            record carries; None: all 0, which sensor_msgs/Imu reads as unknown.

    Returns:
        One message per record.

    Raises:
        ValueError: A stamp is outside the range of builtin_interfaces/Time.
    """
    n = len(np.asarray(time_ns).reshape(-1))
    return cdr_messages(time_ns, frame, imu_values(columns, n, covariance))


def imu_cdr(time_ns: int, frame: str, columns: Mapping[str, npt.ArrayLike],
            covariance: ImuCovariance | None = None) -> bytes:
    """One record's CDR ``sensor_msgs/msg/Imu``.

    Args:
        time_ns: Its stamp, int ns since 1970.
        frame: The frame id (``frame_id``).
        columns: One value of each quantity (``accel`` of shape (3,), ``m`` (3, 3), ...).
        covariance: As ``imu_cdr_batch``'s.

    Returns:
        The message.

    Raises:
        ValueError: The stamp is outside the range of builtin_interfaces/Time.
    """
    one = {k: np.asarray(v, np.float64)[None] for k, v in columns.items()}
    return imu_cdr_batch([time_ns], frame, one, covariance)[0]


def mag_values(columns: Mapping[str, np.ndarray], n: int) -> np.ndarray:
    """The fields of n MagneticField messages after their header.

    The field in tesla in the body FLU frame, covariance 0 (unknown).

    Args:
        columns: The records' ``mag``, or else ``stab_mag``, in gauss, (n, 3).
        n: How many records.

    Returns:
        (n, 12) float64: the field, then its covariance.

    Raises:
        ValueError: A record carries no field (give only those ``has_mag`` picks).
    """
    field, present = _rows(columns, MAGNETOMETER, n, 3)
    if not present.all():
        raise ValueError("a record without a magnetic field cannot be a MagneticField message")
    doubles = np.zeros((n, 12))
    doubles[:, 0:3] = _body_flu(field) * TESLA_PER_GAUSS
    return doubles


def mag_cdr_batch(time_ns: npt.ArrayLike, frame: str,
                  columns: Mapping[str, np.ndarray]) -> list[bytes]:
    """CDR ``sensor_msgs/msg/MagneticField`` of each record (``mag_values``).

    Args:
        time_ns: Each record's stamp, int ns since 1970.
        frame: The frame id (``frame_id``).
        columns: The records' ``mag``, or else ``stab_mag``, in gauss, (n, 3).

    Returns:
        One message per record.

    Raises:
        ValueError: A record carries no field (give only those ``has_mag`` picks), or a
            stamp is outside the range of builtin_interfaces/Time.
    """
    t = np.asarray(time_ns, np.int64).reshape(-1)
    return cdr_messages(t, frame, mag_values(columns, len(t)))
