"""Deterministic ground-truth motion of a simulated 3DM-GX3.

Every quantity a simulated unit reports is derived from one analytic trajectory, so the
outputs are mutually consistent (M, Euler and Q agree; AngRate is the true body rate of
M; DeltaAng integrates AngRate; Accel is the specific force of the same motion) and a
test can check a pipeline against exact values. Samples are a pure function of
(config, t), so a unit can regenerate any sample it has already sent.
"""

from __future__ import annotations

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

_N_ATTITUDE_TERMS = 3
_N_POSITION_TERMS = 2
_MIN_FREQ_HZ = 0.05
_MAX_FREQ_HZ = 0.5
_MAX_PITCH_AMPLITUDE_RAD = np.radians(55.0)
_YAW_DRIFT_PER_AMPLITUDE = 0.25
_GAUSS_NODES, _GAUSS_WEIGHTS = np.polynomial.legendre.leggauss(6)
_GRAVITY_NED_G = np.array([0.0, 0.0, 1.0])
_UINT64_TO_UNIT = 2.0**-53


@dataclass(frozen=True)
class MotionConfig:
    """What a simulated unit experiences; the seed fixes the trajectory and the noise."""

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
    """SplitMix64 finaliser: a cheap, well-mixed hash that NumPy can apply to whole arrays."""
    z = x + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _time_keyed_normals(seed: int, t: FloatArray, count: int) -> FloatArray:
    """(n, count) standard normals that depend only on (seed, round(t * 1e6)).

    A per-sample Generator would be too slow at high rates; hashing the microsecond
    time stamp gives the same determinism vectorised (Box-Muller on hashed uniforms).
    """
    micros = np.round(t * 1e6).astype(np.int64).view(np.uint64)
    key = _splitmix64(np.array([seed & 0xFFFFFFFFFFFFFFFF], dtype=np.uint64))
    base = _splitmix64(micros ^ key)
    pairs = (count + 1) // 2
    streams = np.arange(1, 2 * pairs + 1, dtype=np.uint64) * np.uint64(0xD1B54A32D192ED03)
    bits = _splitmix64(base[:, None] ^ streams[None, :])
    u = ((bits >> np.uint64(11)).astype(np.float64) + 0.5) * _UINT64_TO_UNIT
    radius = np.sqrt(-2.0 * np.log(u[:, :pairs]))
    angle = 2.0 * np.pi * u[:, pairs:]
    normals = np.concatenate([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    return normals[:, :count]


def _sum_of_sines(
    t: FloatArray, amp: FloatArray, omega: FloatArray, phase: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Value and time derivative of sum_k amp sin(omega t + phase) per axis, shape t.shape + (3,)."""
    arg = t[..., None, None] * omega + phase
    value = np.sum(amp * np.sin(arg), axis=-1)
    rate = np.sum(amp * omega * np.cos(arg), axis=-1)
    return value, rate


class Motion:
    """Analytic trajectory of one simulated unit, sampled on demand at any device times.

    Attitude is roll, pitch, yaw, each a sum of sinusoids (plus a slow yaw drift, so yaw
    wraps); linear acceleration in the earth frame is a sum of sinusoids too. Pitch stays
    within +/-55 degrees so Euler angles never meet their singularity.
    """

    def __init__(self, config: MotionConfig | None = None) -> None:
        self.config = config if config is not None else MotionConfig()
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)

        amplitude = max(cfg.attitude_amplitude_rad, 0.0)
        axis_amplitude = np.array(
            [amplitude, min(amplitude, _MAX_PITCH_AMPLITUDE_RAD), 2.0 * amplitude]
        )
        weights = rng.uniform(0.2, 1.0, (3, _N_ATTITUDE_TERMS))
        weights /= weights.sum(axis=1, keepdims=True)
        self._att_amp = axis_amplitude[:, None] * weights
        self._att_omega = 2.0 * np.pi * rng.uniform(_MIN_FREQ_HZ, _MAX_FREQ_HZ, weights.shape)
        self._att_phase = rng.uniform(0.0, 2.0 * np.pi, weights.shape)
        self._att_offset = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        self._att_drift = np.array(
            [0.0, 0.0, rng.uniform(-1.0, 1.0) * _YAW_DRIFT_PER_AMPLITUDE * amplitude]
        )

        lin_weights = rng.uniform(0.2, 1.0, (3, _N_POSITION_TERMS))
        lin_weights /= lin_weights.sum(axis=1, keepdims=True)
        self._lin_amp = max(cfg.linear_accel_amplitude_g, 0.0) * lin_weights
        self._lin_omega = 2.0 * np.pi * rng.uniform(_MIN_FREQ_HZ, _MAX_FREQ_HZ, lin_weights.shape)
        self._lin_phase = rng.uniform(0.0, 2.0 * np.pi, lin_weights.shape)

        self._earth_field = np.asarray(cfg.earth_field_gauss, dtype=np.float64)
        self._gyro_bias = np.asarray(cfg.gyro_bias_rad_s, dtype=np.float64)
        self._accel_bias = np.asarray(cfg.accel_bias_g, dtype=np.float64)
        code0 = round(float(celsius_to_mag_temperature_code(cfg.temperature_c)))
        offsets = rng.integers(-60, 61, 3)
        self._temperature = np.clip(np.concatenate([[code0], code0 + offsets]), 0, 4095).astype(
            np.uint16
        )

    def euler_and_rates(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Unwrapped roll, pitch, yaw [rad] and their time derivatives, shape t.shape + (3,)."""
        tt = np.asarray(t, dtype=np.float64)
        if self.config.static:
            tt = np.zeros_like(tt)
        angles, rates = _sum_of_sines(tt, self._att_amp, self._att_omega, self._att_phase)
        angles = angles + self._att_offset + tt[..., None] * self._att_drift
        if self.config.static:
            return angles, np.zeros_like(rates)
        return angles, rates + self._att_drift

    def linear_accel_earth(self, t: npt.ArrayLike) -> FloatArray:
        """Kinematic acceleration of the unit in the earth (NED) frame [g], shape t.shape + (3,)."""
        tt = np.asarray(t, dtype=np.float64)
        if self.config.static:
            return np.zeros(tt.shape + (3,))
        return _sum_of_sines(tt, self._lin_amp, self._lin_omega, self._lin_phase)[0]

    def _truth(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Noise-free M, body angular rate [rad/s] and specific force [g] at times t."""
        angles, rates = self.euler_and_rates(t)
        m = euler_to_m(angles)
        roll, pitch = angles[..., 0], angles[..., 1]
        droll, dpitch, dyaw = rates[..., 0], rates[..., 1], rates[..., 2]
        sr, cr = np.sin(roll), np.cos(roll)
        sp, cp = np.sin(pitch), np.cos(pitch)
        body_rate = np.stack(
            [
                droll - dyaw * sp,
                dpitch * cr + dyaw * cp * sr,
                -dpitch * sr + dyaw * cp * cr,
            ],
            axis=-1,
        )
        force_earth = self.linear_accel_earth(t) - _GRAVITY_NED_G
        specific_force = np.einsum("...ij,...j->...i", m, force_earth)
        return m, body_rate, specific_force

    def sample(self, t: npt.ArrayLike, period: float) -> dict[str, np.ndarray]:
        """Everything the unit can report at device times t [s], shape (n,).

        period is the output sample period [s]; DeltaAng and DeltaVel integrate over
        [t - period, t] with Gauss-Legendre quadrature. All arrays are float64 except
        temperature, which holds uint16 A/D codes as the device sends them.
        """
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if tt.ndim != 1:
            raise ValueError(f"t must be one-dimensional, got shape {tt.shape}")
        if not period > 0.0:
            raise ValueError(f"period must be positive, got {period}")
        n = tt.shape[0]
        cfg = self.config

        half = 0.5 * period
        nodes = (tt - half)[:, None] + half * _GAUSS_NODES[None, :]
        times = np.concatenate([tt[:, None], (tt - CALCULATION_CYCLE_S)[:, None], nodes], axis=1)
        m_all, rate_all, force_all = self._truth(times)

        m = m_all[:, 0]
        stab_accel = -m[..., :, 2]
        stab_mag = m @ self._earth_field
        ang_rate = rate_all[:, 0] + self._gyro_bias
        accel = force_all[:, 0] + self._accel_bias
        mag = stab_mag.copy()
        delta_ang = half * np.einsum("k,nki->ni", _GAUSS_WEIGHTS, rate_all[:, 2:])
        delta_vel = half * np.einsum("k,nki->ni", _GAUSS_WEIGHTS, force_all[:, 2:])
        delta_ang += self._gyro_bias * period
        delta_vel += self._accel_bias * period

        if cfg.noise_accel_g > 0.0 or cfg.noise_gyro_rad_s > 0.0 or cfg.noise_mag_gauss > 0.0:
            normals = _time_keyed_normals(cfg.seed, tt, 9)
            accel_noise = cfg.noise_accel_g * normals[:, 0:3]
            gyro_noise = cfg.noise_gyro_rad_s * normals[:, 3:6]
            accel += accel_noise
            ang_rate += gyro_noise
            mag += cfg.noise_mag_gauss * normals[:, 6:9]
            delta_vel += accel_noise * period
            delta_ang += gyro_noise * period

        c = m @ np.swapaxes(m_all[:, 1], -1, -2)
        raw_accel = np.clip(RAW_ZERO_CODE + accel * RAW_ACCEL_CODES_PER_G, 0.0, RAW_MAX_CODE)
        raw_ang_rate = np.clip(
            RAW_ZERO_CODE + ang_rate * RAW_GYRO_CODES_PER_RAD_S, 0.0, RAW_MAX_CODE
        )
        return {
            "m": m,
            "euler": m_to_euler(m),
            "quaternion": m_to_quaternion(m),
            "ang_rate": ang_rate,
            "accel": accel,
            "mag": mag,
            "stab_accel": stab_accel,
            "stab_mag": stab_mag,
            "delta_ang": delta_ang,
            "delta_vel": delta_vel,
            "c": c,
            "raw_accel": raw_accel,
            "raw_ang_rate": raw_ang_rate,
            "temperature": np.broadcast_to(self._temperature, (n, 4)).copy(),
        }
