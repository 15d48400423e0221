"""Conversions against the protocol manual's formulas and worked examples."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.protocol.convert import (
    STANDARD_GRAVITY,
    celsius_to_mag_temperature_code,
    euler_to_m,
    euler_to_quaternion,
    fir_response,
    local_gravity,
    m_to_euler,
    m_to_quaternion,
    mag_fir_response,
    mag_fir_response_simplified,
    mag_low_power_fir_response,
    mag_temperature_celsius,
    mag_temperature_celsius_linear,
    quaternion_to_euler,
    quaternion_to_m,
    sensor_to_earth_xyzw,
    ticks_to_seconds,
    wake_time_seconds,
)
from bridge.protocol.table import TICKS_PER_SECOND

settings.register_profile("convert", deadline=None, max_examples=150)
settings.load_profile("convert")

unit = st.floats(-1.0, 1.0, allow_nan=False)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: math.hypot(*q) > 0.1)
angles = st.floats(-math.pi, math.pi, allow_nan=False)
vectors = st.tuples(*(st.floats(-10.0, 10.0, allow_nan=False) for _ in range(3)))


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    """Active rotation matrix by angle about axis (right-hand rule)."""
    u = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    return np.asarray(np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k)


def _hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-first quaternions."""
    p0, pv = p[0], p[1:]
    q0, qv = q[0], q[1:]
    return np.concatenate([[p0 * q0 - pv @ qv], p0 * qv + q0 * pv + np.cross(pv, qv)])


def _rotate_xyzw(q_xyzw: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v' = q v q* with the Hamilton product, for an x, y, z, w quaternion."""
    q = np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    return _hamilton(_hamilton(q, np.concatenate([[0.0], v])), conj)[1:]


def _branch(m: np.ndarray) -> int:
    tests = [
        m[0, 0] + m[1, 1] + m[2, 2],
        m[0, 0] - m[1, 1] - m[2, 2],
        -m[0, 0] + m[1, 1] - m[2, 2],
        -m[0, 0] - m[1, 1] + m[2, 2],
    ]
    return int(np.argmax(tests))


@given(quaternions)
def test_m_to_q_to_m_round_trip(q: tuple[float, float, float, float]) -> None:
    m = quaternion_to_m(q)
    q2 = m_to_quaternion(m)
    assert q2[0] >= 0.0
    np.testing.assert_allclose(np.linalg.norm(q2), 1.0, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_m(q2), m, atol=1e-12)
    qn = np.asarray(q) / np.linalg.norm(q)
    assert min(np.abs(q2 - qn).max(), np.abs(q2 + qn).max()) < 1e-9


@pytest.mark.parametrize(("axis_index", "branch"), [(0, 1), (1, 2), (2, 3)])
@given(
    delta=st.floats(1e-3, 0.2, allow_nan=False),
    tilt=st.tuples(*(st.floats(-0.1, 0.1, allow_nan=False) for _ in range(3))),
)
def test_m_to_q_near_half_turns(
    axis_index: int, branch: int, delta: float, tilt: tuple[float, float, float]
) -> None:
    axis = np.eye(3)[axis_index] + np.asarray(tilt)
    angle = math.pi - delta
    m = _rodrigues(axis, angle).T
    assert _branch(m) == branch
    q = m_to_quaternion(m)
    u = axis / np.linalg.norm(axis)
    expected = np.concatenate([[math.cos(angle / 2)], u * math.sin(angle / 2)])
    np.testing.assert_allclose(q, expected, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_m(q), m, atol=1e-12)


def test_m_to_q_exact_half_turns_stay_unit() -> None:
    for axis in np.eye(3):
        m = _rodrigues(axis, math.pi).T
        q = m_to_quaternion(m)
        assert q[0] >= 0.0
        np.testing.assert_allclose(np.abs(q), np.concatenate([[0.0], axis]), atol=1e-12)
        np.testing.assert_allclose(quaternion_to_m(q), m, atol=1e-12)


@given(angles, st.floats(-math.radians(85), math.radians(85)), angles)
def test_euler_to_m_to_euler(roll: float, pitch: float, yaw: float) -> None:
    back = m_to_euler(euler_to_m([roll, pitch, yaw]))
    wrapped = np.angle(np.exp(1j * (back - [roll, pitch, yaw])))
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-9)


@given(angles, st.floats(-math.pi / 2, math.pi / 2), angles)
def test_euler_to_m_is_a_rotation(roll: float, pitch: float, yaw: float) -> None:
    m = euler_to_m([roll, pitch, yaw])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-12)


@given(quaternions)
def test_q0_never_negative(q: tuple[float, float, float, float]) -> None:
    assert m_to_quaternion(quaternion_to_m(q))[0] >= 0.0
    assert m_to_quaternion(quaternion_to_m(np.negative(q)))[0] >= 0.0


@given(angles, st.floats(-math.radians(85), math.radians(85)), angles)
def test_quaternion_euler_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = euler_to_quaternion([roll, pitch, yaw])
    np.testing.assert_allclose(quaternion_to_m(q), euler_to_m([roll, pitch, yaw]), atol=1e-12)
    wrapped = np.angle(np.exp(1j * (quaternion_to_euler(q) - [roll, pitch, yaw])))
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-9)


@given(quaternions, vectors)
def test_sensor_to_earth_xyzw_matches_m_transpose(
    q: tuple[float, float, float, float], v: tuple[float, float, float]
) -> None:
    m = quaternion_to_m(q)
    v_sensor = np.asarray(v)
    v_earth = _rotate_xyzw(sensor_to_earth_xyzw(q), v_sensor)
    np.testing.assert_allclose(v_earth, m.T @ v_sensor, atol=1e-9)


def test_sensor_to_earth_heading_east() -> None:
    q = euler_to_quaternion([0.0, 0.0, math.pi / 2])
    xyzw = sensor_to_earth_xyzw(q)
    np.testing.assert_allclose(xyzw, [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(_rotate_xyzw(xyzw, np.array([1.0, 0, 0])), [0, 1, 0], atol=1e-12)


def test_identity_attitude() -> None:
    np.testing.assert_allclose(m_to_quaternion(np.eye(3)), [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(euler_to_quaternion([0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(quaternion_to_m([2.0, 0.0, 0.0, 0.0]), np.eye(3))
    np.testing.assert_allclose(m_to_euler(np.eye(3)), [0.0, 0.0, 0.0])


def test_yaw_90_matches_printed_matrix() -> None:
    m = euler_to_m([0.0, 0.0, math.pi / 2])
    # cos(psi)cos(theta), sin(psi)cos(theta), cos(psi)sin(theta)sin(phi) - sin(psi)cos(phi)
    assert m[0, 0] == pytest.approx(0.0, abs=1e-15)
    assert m[0, 1] == pytest.approx(1.0)
    assert m[1, 0] == pytest.approx(-1.0)
    assert m[1, 1] == pytest.approx(0.0, abs=1e-15)
    assert m[2, 2] == pytest.approx(1.0)
    # Facing east, north lies along the sensor's -y axis.
    np.testing.assert_allclose(m @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-15)


def test_pitch_clipped_at_the_singularity() -> None:
    m = euler_to_m([0.0, math.pi / 2, 0.0])
    m[0, 2] = -1.0 - 1e-7
    assert m_to_euler(m)[1] == pytest.approx(math.pi / 2)


def test_vectorised_shapes() -> None:
    rng = np.random.default_rng(1)
    euler = rng.uniform(-1.0, 1.0, (2, 5, 3))
    m = euler_to_m(euler)
    assert m.shape == (2, 5, 3, 3)
    q = m_to_quaternion(m)
    assert q.shape == (2, 5, 4)
    assert q.dtype == np.float64
    np.testing.assert_allclose(quaternion_to_m(q), m, atol=1e-12)
    np.testing.assert_allclose(m_to_euler(m), euler, atol=1e-12)
    assert sensor_to_earth_xyzw(q).shape == (2, 5, 4)
    for i in range(2):
        for j in range(5):
            np.testing.assert_allclose(q[i, j], m_to_quaternion(m[i, j]), atol=1e-15)
    with pytest.raises(ValueError, match="shape"):
        m_to_quaternion(np.eye(4))


def test_example_1_accel_gyro_filter() -> None:
    assert round(float(fir_response(75, 10)), 3) == 0.300


def test_example_2_magnetometer_filter() -> None:
    assert round(float(mag_fir_response(60, 16)), 3) == 0.041
    # The three factors: the fixed 2- and 7-point stages are moving averages at 7500 Hz
    # and 3750 Hz, i.e. Equation 5's form with those rates; the last is Equation 4.
    assert round(float(mag_low_power_fir_response(60, 2, 7500)), 4) == 0.9997
    assert round(float(mag_low_power_fir_response(60, 7, 3750)), 4) == 0.9799
    assert round(float(mag_fir_response_simplified(60, 16)), 4) == 0.0418


def test_filter_responses_at_dc() -> None:
    f = np.array([0.0, 1e-9, 10.0, 1000.0])
    for response in (
        fir_response(f, 10),
        mag_fir_response(f, 16),
        mag_fir_response_simplified(f, 16),
        mag_low_power_fir_response(f, 8, 100.0),
    ):
        h = np.asarray(response)
        assert np.all(np.isfinite(h))
        assert h[0] == 1.0
        assert h[1] == pytest.approx(1.0)
        assert np.all((h >= 0.0) & (h <= 1.0 + 1e-12))
    assert fir_response(0.0, 1) == 1.0
    assert fir_response(1000.0, 10) == pytest.approx(0.0, abs=1e-12)


def test_local_gravity_example() -> None:
    g = local_gravity(10, 1000)
    assert round(float(g), 5) == 9.77879
    assert round(float(g / STANDARD_GRAVITY), 5) == 0.99716


def test_mag_temperature_formulas_agree_near_room_temperature() -> None:
    celsius = np.arange(15.0, 36.0)
    codes = np.round(celsius_to_mag_temperature_code(celsius))
    exact = mag_temperature_celsius(codes)
    linear = mag_temperature_celsius_linear(codes)
    assert np.all(np.abs(exact - linear) < 2.0)
    assert np.all(np.abs(exact - celsius) < 2.0)


@given(st.floats(-40.0, 85.0))
def test_linear_temperature_inverse_round_trips(celsius: float) -> None:
    code = celsius_to_mag_temperature_code(celsius)
    assert mag_temperature_celsius_linear(code) == pytest.approx(celsius, abs=1e-9)


def test_timer_and_wake_time() -> None:
    assert TICKS_PER_SECOND == 62_500
    assert ticks_to_seconds(62_500) == 1.0
    assert ticks_to_seconds(2**32 - 1) == pytest.approx(68719.47672)
    np.testing.assert_allclose(ticks_to_seconds(np.array([0, 625])), [0.0, 0.01])
    assert wake_time_seconds(10) == pytest.approx(0.073)
    assert isinstance(wake_time_seconds(10), np.float64)
