"""Deterministic ground-truth motion of a simulated 3DM-GX3.

Every quantity a simulated unit reports comes from one analytic trajectory, so the outputs
agree with each other (M, Euler and Q describe one attitude; AngRate is the body rate of M;
DeltaAng integrates AngRate; Accel is the specific force of the same motion) and tests can
check a pipeline against exact values. A sample is a pure function of (config, t), never of
the other times in its batch, so a unit can regenerate any sample it has sent (up to the
last float64 bit, as NumPy's vector and scalar sin may round differently).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from bridge.protocol.convert import (
    celsius_to_mag_temperature_code,
    euler_to_m,
    m_to_euler,
    m_to_quaternion,
)

FloatArray = npt.NDArray[np.float64]

RAW_ZERO_CODE = 65536.0
RAW_MAX_CODE = 131071.0
RAW_ACCEL_CODES_PER_G = 8000.0
RAW_GYRO_CODES_PER_RAD_S = 3000.0
CALCULATION_CYCLE_S = 0.001

_FREQ_RANGE_HZ = (0.05, 0.5)
_MAX_PITCH_AMPLITUDE_RAD = math.radians(55.0)  # keeps Euler angles clear of gimbal lock
_YAW_DRIFT_PER_AMPLITUDE = 0.25
_MIN_GAUSS_NODES = 5
_LOG_QUADRATURE_TOLERANCE = math.log(1e-17)
_GRAVITY_NED_G = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class MotionConfig:
    """What a simulated unit experiences; the seed fixes the trajectory and the noise.

    static freezes the seed's attitude (zero rate, gravity-only accel). The biases are
    the sensor's own true offsets, added to what it reports, so that a stationary bias
    capture (0xCD) has something to find. Noise is white Gaussian, zero by default.
    earth_field_gauss is north-east-down.
    """

    seed: int = 0
    static: bool = False
    attitude_amplitude_rad: float = 0.6
    linear_accel_amplitude_g: float = 0.2
    earth_field_gauss: tuple[float, float, float] = (0.2, 0.0, 0.45)
    gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias_g: tuple[float, float, float] = (0.0, 0.0, 0.0)
    noise_accel_g: float = 0.0
    noise_gyro_rad_s: float = 0.0
    noise_mag_gauss: float = 0.0
    temperature_c: float = 25.0


def _splitmix64(x: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    """SplitMix64: a well-mixed 64-bit hash that NumPy applies to whole arrays."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _time_keyed_normals(seed: int, t: FloatArray, count: int) -> FloatArray:
    """(n, count) standard normals that depend only on (seed, t rounded to 1 us).

    Hashing the time stamp, rather than drawing from a generator, keeps a sample's noise
    independent of the batch it is computed in; Box-Muller turns the hashes into normals.
    """
    micros = np.round(t * 1e6).astype(np.int64).view(np.uint64)
    key = _splitmix64(np.array([seed & 0xFFFF_FFFF_FFFF_FFFF], dtype=np.uint64))
    pairs = (count + 1) // 2
    streams = np.arange(1, 2 * pairs + 1, dtype=np.uint64) * np.uint64(0xD1B54A32D192ED03)
    bits = _splitmix64(streams ^ _splitmix64(micros ^ key)[:, None])
    u = ((bits >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0**-53  # uniform in (0, 1)
    radius, angle = np.sqrt(-2.0 * np.log(u[:, :pairs])), 2.0 * np.pi * u[:, pairs:]
    return np.concatenate([radius * np.cos(angle), radius * np.sin(angle)], axis=1)[:, :count]


@functools.cache
def _gauss_legendre(n: int) -> tuple[FloatArray, FloatArray]:
    return np.polynomial.legendre.leggauss(n)


def _rotate(m: FloatArray, v: FloatArray) -> FloatArray:
    """m @ v over stacks: (..., 3, 3) and (..., 3) -> (..., 3)."""
    return np.einsum("...ij,...j->...i", m, v)


class Motion:
    """Analytic trajectory of one simulated unit, sampled on demand at any device times.

    Roll, pitch and yaw are each a sum of sinusoids (plus a slow yaw drift, so yaw wraps);
    the earth-frame linear acceleration is a sum of sinusoids too. Pitch stays within
    +/-55 degrees so Euler angles never meet their singularity. A static config freezes
    the trajectory at its t = 0 attitude.
    """

    def __init__(self, config: MotionConfig | None = None) -> None:
        self.config = cfg = config if config is not None else MotionConfig()
        rng = np.random.default_rng(cfg.seed)

        # Attitude: 3 terms per axis whose amplitudes sum to the axis amplitude.
        amplitude = max(cfg.attitude_amplitude_rad, 0.0)
        axis_amp = np.array([amplitude, min(amplitude, _MAX_PITCH_AMPLITUDE_RAD), 2 * amplitude])
        share = rng.uniform(0.2, 1.0, (3, 3))
        self._att_amp = axis_amp[:, None] * share / share.sum(axis=1, keepdims=True)
        self._att_omega = 2.0 * np.pi * rng.uniform(*_FREQ_RANGE_HZ, (3, 3))
        self._att_phase = rng.uniform(0.0, 2.0 * np.pi, (3, 3))
        self._att_offset = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        yaw_drift = rng.uniform(-1.0, 1.0) * _YAW_DRIFT_PER_AMPLITUDE * amplitude
        self._att_drift = np.array([0.0, 0.0, yaw_drift])

        # Linear acceleration: 2 terms per earth axis.
        share = rng.uniform(0.2, 1.0, (3, 2))
        lin_amp = max(cfg.linear_accel_amplitude_g, 0.0)
        self._lin_amp = lin_amp * share / share.sum(axis=1, keepdims=True)
        self._lin_omega = 2.0 * np.pi * rng.uniform(*_FREQ_RANGE_HZ, (3, 2))
        self._lin_phase = rng.uniform(0.0, 2.0 * np.pi, (3, 2))

        code0 = round(float(celsius_to_mag_temperature_code(cfg.temperature_c)))
        codes = np.concatenate([[code0], code0 + rng.integers(-60, 61, 3)])
        self._temperature = np.clip(codes, 0, 4095).astype(np.uint16)

        if cfg.static:
            self._att_offset = self._att_offset + self.euler_and_rates(0.0)[0]
            self._att_amp = np.zeros_like(self._att_amp)
            self._att_drift = np.zeros(3)
            self._lin_amp = np.zeros_like(self._lin_amp)

        self._earth_field = np.asarray(cfg.earth_field_gauss, dtype=np.float64)
        self._gyro_bias = np.asarray(cfg.gyro_bias_rad_s, dtype=np.float64)
        self._accel_bias = np.asarray(cfg.accel_bias_g, dtype=np.float64)
        # The quadrature integrands contain sin/cos of the Euler angles, which turn at up
        # to the peak Euler rate on top of the terms' own frequencies: a bandwidth bound.
        max_euler_rate = np.max(np.abs(self._att_amp * self._att_omega).sum(axis=1))
        max_euler_rate += np.abs(self._att_drift).max()
        max_omega = max(self._att_omega.max(), self._lin_omega.max())
        self._bandwidth_rad_s = float(3.0 * max_euler_rate + 2.0 * max_omega)

    def euler_and_rates(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Unwrapped roll, pitch, yaw [rad] and their time derivatives, shape t.shape + (3,)."""
        t = np.asarray(t, dtype=np.float64)[..., None]
        phase = t[..., None] * self._att_omega + self._att_phase
        euler = np.sum(self._att_amp * np.sin(phase), axis=-1)
        rates = np.sum(self._att_amp * self._att_omega * np.cos(phase), axis=-1)
        return euler + self._att_offset + self._att_drift * t, rates + self._att_drift

    def linear_accel_earth(self, t: npt.ArrayLike) -> FloatArray:
        """Kinematic acceleration of the unit in the earth (NED) frame [g], shape t.shape + (3,)."""
        t = np.asarray(t, dtype=np.float64)
        phase = t[..., None, None] * self._lin_omega + self._lin_phase
        return np.sum(self._lin_amp * np.sin(phase), axis=-1)

    def _node_count(self, half_period: float) -> int:
        """Gauss-Legendre nodes enough for float64-exact deltas, however long the period.

        n nodes integrate polynomials of degree 2n - 1 exactly, so for an integrand of
        bandwidth B over half-width h the error is about (B h)**(2n) / (2n)!.
        """
        log_x = math.log(max(self._bandwidth_rad_s * half_period, 1e-300))
        n = _MIN_GAUSS_NODES
        while 2 * n * log_x - math.lgamma(2 * n + 1) > _LOG_QUADRATURE_TOLERANCE:
            n += 1
        return n

    def _kinematics(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """True M, body rate [rad/s] and specific force [g] at times t of any shape."""
        euler, euler_rate = self.euler_and_rates(t)
        droll, dpitch, dyaw = np.moveaxis(euler_rate, -1, 0)
        sr, sp = np.sin(euler[..., 0]), np.sin(euler[..., 1])
        cr, cp = np.cos(euler[..., 0]), np.cos(euler[..., 1])
        # ZYX kinematics: the sensor-frame rate of M = Rx(roll) Ry(pitch) Rz(yaw).
        body_rate = np.stack(
            [droll - dyaw * sp, dpitch * cr + dyaw * cp * sr, dyaw * cp * cr - dpitch * sr],
            axis=-1,
        )
        m = euler_to_m(euler)
        specific_force = _rotate(m, self.linear_accel_earth(t) - _GRAVITY_NED_G)
        return m, body_rate, specific_force

    def sample(self, t: npt.ArrayLike, period: float) -> dict[str, np.ndarray]:
        """Everything the unit can report at device times t [s], shape (n,).

        period is the output sample period [s]: DeltaAng and DeltaVel integrate over
        [t - period, t] by Gauss-Legendre quadrature, and C spans the last 1 ms
        calculation cycle. All arrays are float64 except temperature, which holds the
        uint16 A/D codes the device sends. Biases and noise affect only the sensor
        readings (accel, ang_rate, mag, deltas, raw codes), never M or C.
        """
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if t.ndim != 1:
            raise ValueError(f"t must be one-dimensional, got shape {t.shape}")
        if not period > 0.0:
            raise ValueError(f"period must be positive, got {period}")
        cfg = self.config

        # One evaluation at (offsets, n) times: now, one calculation cycle ago (for C),
        # then the quadrature nodes in [t - period, t].
        half = 0.5 * period
        nodes, weights = _gauss_legendre(self._node_count(half))
        offsets = np.concatenate([[0.0, -CALCULATION_CYCLE_S], half * (nodes - 1.0)])
        m_all, rate_all, force_all = self._kinematics(t + offsets[:, None])
        m = m_all[0]
        w = half * weights[:, None, None]
        delta_ang = np.sum(w * rate_all[2:], axis=0) + self._gyro_bias * period
        delta_vel = np.sum(w * force_all[2:], axis=0) + self._accel_bias * period
        stab_mag = _rotate(m, self._earth_field)

        sigma = np.repeat([cfg.noise_accel_g, cfg.noise_gyro_rad_s, cfg.noise_mag_gauss], 3)
        noise = sigma * _time_keyed_normals(cfg.seed, t, 9) if sigma.any() else np.zeros((1, 9))
        accel = force_all[0] + self._accel_bias + noise[:, 0:3]
        ang_rate = rate_all[0] + self._gyro_bias + noise[:, 3:6]
        return {
            "m": m,
            "euler": m_to_euler(m),
            "quaternion": m_to_quaternion(m),
            "ang_rate": ang_rate,
            "accel": accel,
            "mag": stab_mag + noise[:, 6:9],
            "stab_accel": -m[:, :, 2],
            "stab_mag": stab_mag,
            "delta_ang": delta_ang + noise[:, 3:6] * period,
            "delta_vel": delta_vel + noise[:, 0:3] * period,
            "c": m @ m_all[1].swapaxes(-1, -2),
            "raw_accel": np.clip(RAW_ZERO_CODE + accel * RAW_ACCEL_CODES_PER_G, 0, RAW_MAX_CODE),
            "raw_ang_rate": np.clip(
                RAW_ZERO_CODE + ang_rate * RAW_GYRO_CODES_PER_RAD_S, 0, RAW_MAX_CODE
            ),
            "temperature": np.tile(self._temperature, (t.shape[0], 1)),
        }
