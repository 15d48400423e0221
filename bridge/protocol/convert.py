"""Unit and orientation conversions from the 3DM-GX3 Data Communications Protocol manual.

Everything here is pure NumPy and vectorised over leading axes, so the same code
converts one reply or a whole recording. Orientation conventions follow the manual:
M maps earth (north-east-down) vectors into the sensor frame, v_local = M @ v_earth,
and quaternions are scalar-first (q0, q1, q2, q3).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND

FloatArray = npt.NDArray[np.float64]
FloatOut = FloatArray | np.float64

STANDARD_GRAVITY = 9.80665

_DIRICHLET_EPS = 1e-12


def _f64(x: npt.ArrayLike) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


def _out(x: npt.ArrayLike) -> FloatOut:
    """Return a NumPy scalar for 0-d results so scalar callers get a plain number back."""
    return np.asarray(x, dtype=np.float64)[()]


def _check_shape(a: FloatArray, tail: tuple[int, ...], name: str) -> None:
    if a.ndim < len(tail) or a.shape[a.ndim - len(tail) :] != tail:
        raise ValueError(
            f"{name} must have shape (..., {', '.join(map(str, tail))}), got {a.shape}"
        )


def _dirichlet(x: FloatArray, n: FloatArray | float) -> FloatArray:
    """sin(n x) / (n sin x), the moving-average response, with its limit where sin x = 0.

    The manual's filter equations are 0/0 at f = 0 (and at multiples of the stage rate);
    l'Hôpital gives cos(n x) / cos(x) there, which is 1 at f = 0.
    """
    s = np.sin(x)
    small = np.abs(s) < _DIRICHLET_EPS
    safe = np.where(small, 1.0, n * s)
    return _f64(np.where(small, np.cos(n * x) / np.cos(x), np.sin(n * x) / safe))


def euler_to_m(euler: npt.ArrayLike) -> FloatArray:
    """Manual "Euler to M": roll, pitch, yaw to the earth-to-sensor orientation matrix.

    Args:
        euler: (..., 3) roll, pitch, yaw [rad].

    Returns:
        (..., 3, 3) M, v_local = M @ v_earth.

    Raises:
        ValueError: ``euler``'s last axis is not 3 long.
    """
    e = _f64(euler)
    _check_shape(e, (3,), "euler")
    sr, sp, sy = np.sin(e[..., 0]), np.sin(e[..., 1]), np.sin(e[..., 2])
    cr, cp, cy = np.cos(e[..., 0]), np.cos(e[..., 1]), np.cos(e[..., 2])
    m = np.empty((*e.shape[:-1], 3, 3), dtype=np.float64)
    m[..., 0, 0] = cy * cp
    m[..., 0, 1] = sy * cp
    m[..., 0, 2] = -sp
    m[..., 1, 0] = cy * sp * sr - sy * cr
    m[..., 1, 1] = sy * sp * sr + cy * cr
    m[..., 1, 2] = cp * sr
    m[..., 2, 0] = cy * sp * cr + sy * sr
    m[..., 2, 1] = sy * sp * cr - cy * sr
    m[..., 2, 2] = cp * cr
    return m


def m_to_euler(m: npt.ArrayLike) -> FloatArray:
    """Manual "M to Euler" (ZYX / aircraft): orientation matrix to roll, pitch, yaw.

    The arcsine argument is clipped because a float32 M from the device can stray past
    +/-1 near pitch = +/-90 degrees; atan2 resolves the quadrant as the manual advises.

    Args:
        m: (..., 3, 3) earth-to-sensor M.

    Returns:
        (..., 3) roll, pitch, yaw [rad].

    Raises:
        ValueError: ``m`` does not end in (3, 3).
    """
    a = _f64(m)
    _check_shape(a, (3, 3), "m")
    pitch = np.arcsin(np.clip(-a[..., 0, 2], -1.0, 1.0))
    roll = np.arctan2(a[..., 1, 2], a[..., 2, 2])
    yaw = np.arctan2(a[..., 0, 1], a[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def m_to_quaternion(m: npt.ArrayLike) -> FloatArray:
    """Manual "M to Q": orientation matrix to a scalar-first quaternion with q0 >= 0.

    The manual picks whichever of its four formulas has the largest test value, because
    each one loses precision when its own square root approaches zero. All four are
    evaluated and the winner selected per element, so no Python loop is needed.

    Args:
        m: (..., 3, 3) earth-to-sensor M.

    Returns:
        (..., 4) q0 (scalar), q1, q2, q3.

    Raises:
        ValueError: ``m`` does not end in (3, 3).
    """
    a = _f64(m)
    _check_shape(a, (3, 3), "m")
    m11, m12, m13 = a[..., 0, 0], a[..., 0, 1], a[..., 0, 2]
    m21, m22, m23 = a[..., 1, 0], a[..., 1, 1], a[..., 1, 2]
    m31, m32, m33 = a[..., 2, 0], a[..., 2, 1], a[..., 2, 2]

    tests = np.stack(
        [m11 + m22 + m33, m11 - m22 - m33, -m11 + m22 - m33, -m11 - m22 + m33], axis=-1
    )
    s = 2.0 * np.sqrt(np.maximum(1.0 + tests, 0.0))
    s = np.where(s > 0.0, s, 1.0)
    s1, s2, s3, s4 = s[..., 0], s[..., 1], s[..., 2], s[..., 3]

    candidates = np.stack(
        [
            np.stack([s1 / 4, (m23 - m32) / s1, (m31 - m13) / s1, (m12 - m21) / s1], axis=-1),
            np.stack([(m32 - m23) / s2, -s2 / 4, -(m21 + m12) / s2, -(m13 + m31) / s2], axis=-1),
            np.stack([(m13 - m31) / s3, -(m21 + m12) / s3, -s3 / 4, -(m32 + m23) / s3], axis=-1),
            np.stack([(m21 - m12) / s4, -(m13 + m31) / s4, -(m32 + m23) / s4, -s4 / 4], axis=-1),
        ],
        axis=-2,
    )
    branch = np.argmax(tests, axis=-1)[..., None, None]
    q = np.take_along_axis(candidates, branch, axis=-2)[..., 0, :]
    return np.where(q[..., :1] < 0.0, -q, q)


def quaternion_to_m(q: npt.ArrayLike) -> FloatArray:
    """Manual "Q to M": scalar-first quaternion to the earth-to-sensor orientation matrix.

    The quaternion is normalised first so float32 round-off in a device reply does not
    turn into a non-orthogonal matrix.

    Args:
        q: (..., 4) q0 (scalar), q1, q2, q3.

    Returns:
        (..., 3, 3) M.

    Raises:
        ValueError: ``q``'s last axis is not 4 long.
    """
    a = _f64(q)
    _check_shape(a, (4,), "q")
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    q0, q1, q2, q3 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    m = np.empty((*a.shape[:-1], 3, 3), dtype=np.float64)
    m[..., 0, 0] = q0 * q0 - 0.5 + q1 * q1
    m[..., 0, 1] = q1 * q2 + q0 * q3
    m[..., 0, 2] = q1 * q3 - q0 * q2
    m[..., 1, 0] = q1 * q2 - q0 * q3
    m[..., 1, 1] = q0 * q0 - 0.5 + q2 * q2
    m[..., 1, 2] = q2 * q3 + q0 * q1
    m[..., 2, 0] = q1 * q3 + q0 * q2
    m[..., 2, 1] = q2 * q3 - q0 * q1
    m[..., 2, 2] = q0 * q0 - 0.5 + q3 * q3
    return 2.0 * m


def quaternion_to_euler(q: npt.ArrayLike) -> FloatArray:
    """Quaternion to roll, pitch, yaw, through M as the manual prescribes.

    Args:
        q: (..., 4) scalar-first quaternion.

    Returns:
        (..., 3) roll, pitch, yaw [rad].
    """
    return m_to_euler(quaternion_to_m(q))


def euler_to_quaternion(euler: npt.ArrayLike) -> FloatArray:
    """Roll, pitch, yaw to a quaternion, through M as the manual prescribes.

    Args:
        euler: (..., 3) roll, pitch, yaw [rad].

    Returns:
        (..., 4) scalar-first quaternion, q0 >= 0.
    """
    return m_to_quaternion(euler_to_m(euler))


def sensor_to_earth_xyzw(q: npt.ArrayLike) -> FloatArray:
    """Manual Q (scalar-first) to the x, y, z, w quaternion of the sensor-to-earth rotation.

    This is what a renderer such as Rerun wants: a Hamilton quaternion that rotates a
    sensor-frame vector into the earth (north-east-down) frame, i.e. the rotation M.T.
    The manual writes v_local = Q v_earth Q*, but its own "Q to M" formula equals the
    *transpose* of the Hamilton rotation matrix of Q; with the Hamilton product (which
    Rerun uses) Q therefore already maps sensor to earth, v_earth = Q v_local Q*. So no
    conjugate is taken: the components are normalised and reordered from wxyz to xyzw.

    Args:
        q: (..., 4) the manual's quaternion, q0 (scalar) first.

    Returns:
        (..., 4) x, y, z, w, normalised.

    Raises:
        ValueError: ``q``'s last axis is not 4 long.
    """
    a = _f64(q)
    _check_shape(a, (4,), "q")
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return _f64(a[..., [1, 2, 3, 0]])


def rotation_to_xyzw(r: npt.ArrayLike) -> FloatArray:
    """A rotation matrix's Hamilton quaternion, x, y, z, w, as ROS, Rerun and SciPy take it.

    ``r`` turns vectors actively, v' = r @ v. The manual's "M to Q" gives the quaternion
    whose matrix is M's transpose (see ``sensor_to_earth_xyzw``), so it is applied to
    r's transpose; w >= 0.

    Args:
        r: (..., 3, 3) proper rotation matrices.

    Returns:
        (..., 4) x, y, z, w.

    Raises:
        ValueError: ``r`` does not end in (3, 3).
    """
    return _f64(m_to_quaternion(np.swapaxes(_f64(r), -1, -2))[..., [1, 2, 3, 0]])


def xyzw_to_rotation(q: npt.ArrayLike) -> FloatArray:
    """The rotation matrix of a Hamilton quaternion x, y, z, w (``rotation_to_xyzw``'s).

    Args:
        q: (..., 4) x, y, z, w; normalised first.

    Returns:
        (..., 3, 3) r, v' = r @ v.

    Raises:
        ValueError: ``q``'s last axis is not 4 long.
    """
    a = _f64(q)
    _check_shape(a, (4,), "q")
    return _f64(np.swapaxes(quaternion_to_m(a[..., [3, 0, 1, 2]]), -1, -2))


def ticks_to_seconds(ticks: npt.ArrayLike) -> FloatOut:
    """Device timer ticks to seconds (the GX3 timer runs at 62,500 ticks per second).

    Args:
        ticks: Ticks, any shape.

    Returns:
        Seconds, of the same shape (a NumPy scalar for a scalar).
    """
    return _out(_f64(ticks) / TICKS_PER_SECOND)


def mag_temperature_celsius(code: npt.ArrayLike) -> FloatOut:
    """Equation 15: magnetometer-board temperature code to degrees C (the accurate form).

    Args:
        code: The 12-bit code (0xD1's first temperature), any shape.

    Returns:
        Degrees C, of the same shape.
    """
    c = _f64(code)
    return _out(-1481.96 + np.sqrt(2.1962e6 + (1.8639 - 3.0 * c / 4096.0) / 3.88e-6))


def mag_temperature_celsius_linear(code: npt.ArrayLike) -> FloatOut:
    """Equation 16: the manual's linear approximation, valid from -40 to +85 degrees C.

    Args:
        code: The 12-bit magnetometer-board temperature code, any shape.

    Returns:
        Degrees C, of the same shape.
    """
    c = _f64(code)
    return _out(-((3.0 * c / 4096.0) - 1.8583) / 11.67e-3)


def celsius_to_mag_temperature_code(celsius: npt.ArrayLike) -> FloatOut:
    """Inverse of Equation 16, so a simulator can report a chosen temperature.

    Args:
        celsius: Degrees C, any shape.

    Returns:
        The magnetometer-board temperature code, unrounded, of the same shape.
    """
    t = _f64(celsius)
    return _out((1.8583 - 11.67e-3 * t) * 4096.0 / 3.0)


def local_gravity(latitude_deg: npt.ArrayLike, altitude_m: npt.ArrayLike) -> FloatOut:
    """Equation 9: local gravity; a static unit's |Accel| is this / STANDARD_GRAVITY.

    Args:
        latitude_deg: Latitude [degrees].
        altitude_m: Altitude [m].

    Returns:
        Gravity [m/s^2], broadcast over the arguments.
    """
    lat = np.radians(_f64(latitude_deg))
    h = _f64(altitude_m)
    g = 9.780318 * (1.0 + 0.0053024 * np.sin(lat) ** 2 - 0.0000058 * np.sin(2.0 * lat) ** 2)
    return _out(g - 3.086e-6 * h)


def fir_response(f_hz: npt.ArrayLike, width: npt.ArrayLike) -> FloatOut:
    """Equation 2: |H| of the accel/gyro filter (30-tap 30 kHz stage, width-M 1 kHz stage).

    Args:
        f_hz: Frequency [Hz].
        width: The filter width M (0xDB ``filter_width``).

    Returns:
        The gain, broadcast over the arguments.
    """
    f = _f64(f_hz)
    m = _f64(width)
    h = _dirichlet(np.pi * f / 1000.0, m) * _dirichlet(np.pi * f / 30000.0, 30.0)
    return _out(np.abs(h))


def mag_fir_response(f_hz: npt.ArrayLike, width: npt.ArrayLike) -> FloatOut:
    """Equation 3: |H| of the high-resolution magnetometer filter (2-point, 7-point, width M).

    Args:
        f_hz: Frequency [Hz].
        width: The filter width M (0xDB ``mag_filter_width``).

    Returns:
        The gain, broadcast over the arguments.
    """
    f = _f64(f_hz)
    m = _f64(width)
    h = (
        _dirichlet(np.pi * f / 7500.0, 2.0)
        * _dirichlet(np.pi * f / 3750.0, 7.0)
        * _dirichlet(np.pi * f / 1000.0, m)
    )
    return _out(np.abs(h))


def mag_fir_response_simplified(f_hz: npt.ArrayLike, width: npt.ArrayLike) -> FloatOut:
    """Equation 4: only the adjustable stage, as the fixed stages are ~1 below a few hundred Hz.

    Args:
        f_hz: Frequency [Hz].
        width: The filter width M (0xDB ``mag_filter_width``).

    Returns:
        The gain, broadcast over the arguments.
    """
    return _out(np.abs(_dirichlet(np.pi * _f64(f_hz) / 1000.0, _f64(width))))


def mag_low_power_fir_response(
    f_hz: npt.ArrayLike, width: npt.ArrayLike, data_rate_hz: npt.ArrayLike
) -> FloatOut:
    """Equation 5: low-power magnetometer mode, where the adjustable stage runs at the data rate.

    Args:
        f_hz: Frequency [Hz].
        width: The filter width M (0xDB ``mag_filter_width``).
        data_rate_hz: The output data rate [Hz].

    Returns:
        The gain, broadcast over the arguments.
    """
    x = np.pi * _f64(f_hz) / _f64(data_rate_hz)
    return _out(np.abs(_dirichlet(x, _f64(width))))


def wake_time_seconds(filter_width: npt.ArrayLike) -> FloatOut:
    """Equation 1: approximate time from wake-up to the first valid data.

    Args:
        filter_width: The filter width M (0xDB ``filter_width``).

    Returns:
        Seconds, of the same shape.
    """
    return _out(0.053 + 2.0 * _f64(filter_width) / 1000.0)
