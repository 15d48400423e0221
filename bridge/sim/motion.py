"""Deterministic ground-truth motion of a simulated 3DM-GX3.

Every quantity a simulated unit reports is derived from one analytic trajectory, so the
outputs are mutually consistent (M, Euler and Q agree; AngRate is the true body rate of
M; DeltaAng integrates AngRate; Accel is the specific force of the same motion) and a
test can check a pipeline against exact values. Samples are a pure function of
(config, t), so a unit can regenerate any sample it has already sent: the same call
gives identical arrays, and a sample computed within another batch agrees to the last
float64 bit or so (NumPy's vector and scalar libm loops may round differently), far
below the float32 the unit sends. Nothing depends on the other times in a batch.
"""

from __future__ import annotations

import functools
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
_N_LINEAR_TERMS = 2
_MIN_FREQ_HZ = 0.05
_MAX_FREQ_HZ = 0.5
_MAX_PITCH_AMPLITUDE_RAD = float(np.radians(55.0))
_YAW_DRIFT_PER_AMPLITUDE = 0.25
_MIN_GAUSS_NODES = 5
_SERIES_TOLERANCE = 1e-17
_GRAVITY_NED_G = np.array([0.0, 0.0, 1.0])
_TAYLOR_MAX_STEP_RAD = 1.0
_UINT64_TO_UNIT = 2.0**-53


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
    """SplitMix64 finaliser: a cheap, well-mixed hash that NumPy can apply to whole arrays."""
    z = x + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _time_keyed_normals(seed: int, t: FloatArray, count: int) -> FloatArray:
    """(count, n) standard normals that depend only on (seed, round(t * 1e6)).

    A Generator per sample would be far too slow at high rates; hashing the microsecond
    time stamp gives the same per-sample determinism vectorised (Box-Muller on hashed
    uniforms), so a sample's noise does not depend on the batch it is generated in.
    """
    micros = np.round(t * 1e6).astype(np.int64).view(np.uint64)
    key = _splitmix64(np.array([seed & 0xFFFF_FFFF_FFFF_FFFF], dtype=np.uint64))
    base = _splitmix64(micros ^ key)
    pairs = (count + 1) // 2
    streams = np.arange(1, 2 * pairs + 1, dtype=np.uint64) * np.uint64(0xD1B54A32D192ED03)
    bits = _splitmix64(streams[:, None] ^ base[None, :])
    u = ((bits >> np.uint64(11)).astype(np.float64) + 0.5) * _UINT64_TO_UNIT
    radius = np.sqrt(-2.0 * np.log(u[:pairs]))
    angle = 2.0 * np.pi * u[pairs:]
    return np.concatenate([radius * np.cos(angle), radius * np.sin(angle)])[:count]


def _series_order(x: float) -> int:
    """Smallest k with x**k / k! below _SERIES_TOLERANCE: the order a series in x needs."""
    k, term = 1, x
    while term >= _SERIES_TOLERANCE:
        k += 1
        term *= x / k
    return k


@functools.cache
def _gauss_legendre(n: int) -> tuple[FloatArray, FloatArray]:
    return np.polynomial.legendre.leggauss(n)


def _taylor_sincos(x: FloatArray, bound: float) -> tuple[FloatArray, FloatArray]:
    """sin and cos by nested Taylor series for |x| <= bound <= 1: far cheaper than libm.

    The number of terms follows from the bound, so the usual tiny steps cost only a few
    multiply-adds while the result stays float64-exact. Updates are in place to spare
    the allocator, which costs more than the arithmetic here.
    """
    x2 = x * x
    s = np.ones_like(x)
    c = np.ones_like(x)
    for k in range(2 * max(1, (_series_order(bound) - 1) // 2), 0, -2):
        s *= x2
        s *= -1.0 / (k * (k + 1))
        s += 1.0
        c *= x2
        c *= -1.0 / ((k - 1) * k)
        c += 1.0
    s *= x
    return s, c


def _sincos_near(
    sin0: FloatArray, cos0: FloatArray, delta: FloatArray, bound: float
) -> tuple[FloatArray, FloatArray]:
    """sin and cos of (a0 + delta) from those of a0, by the angle-addition formulas.

    bound is an upper limit of |delta| known in advance (not measured from the data), so
    a sample takes the same arithmetic path whatever batch it is in. delta is consumed
    as scratch space.
    """
    if bound <= _TAYLOR_MAX_STEP_RAD:
        sd, cd = _taylor_sincos(delta, bound)
    else:
        sd, cd = np.sin(delta), np.cos(delta)
    sin = sin0 * cd
    sin += np.multiply(cos0, sd, out=delta)
    cd *= cos0
    sd *= sin0
    cd -= sd
    return sin, cd


def _euler_rotate(sin: FloatArray, cos: FloatArray, v: FloatArray) -> FloatArray:
    """M @ v for the manual's Euler-to-M matrix, component-first, without forming M.

    M = Rx(roll) Ry(pitch) Rz(yaw) as frame rotations, so applying them one axis at a
    time is the same product as convert.euler_to_m in a third of the arithmetic and
    without a (3, 3, ...) temporary; sin and cos are those of (roll, pitch, yaw).
    """
    sr, sp, sy = sin
    cr, cp, cy = cos
    out = np.empty(np.broadcast_shapes(sin.shape, v.shape))
    scratch = np.empty(out.shape[1:])
    x = np.multiply(cy, v[0], out=out[0])
    x += np.multiply(sy, v[1], out=scratch)
    y = np.multiply(cy, v[1], out=out[1])
    y -= np.multiply(sy, v[0], out=scratch)
    z = np.multiply(sp, x, out=out[2])
    z += np.multiply(cp, v[2], out=scratch)
    x *= cp
    x -= np.multiply(sp, v[2], out=scratch)
    sr_y = sr * y
    y *= cr
    y += np.multiply(sr, z, out=scratch)
    z *= cr
    z -= sr_y
    return out


def _body_rate(sin: FloatArray, cos: FloatArray, euler_rate: FloatArray) -> FloatArray:
    """ZYX kinematics, component-first: sensor-frame angular rate from Euler angle rates."""
    sr, sp = sin[0], sin[1]
    cr, cp = cos[0], cos[1]
    droll, dpitch, dyaw = euler_rate
    out = np.empty(sin.shape)
    scratch = np.empty(sin.shape[1:])
    yaw_cp = np.multiply(dyaw, cp, out=out[2])
    np.multiply(yaw_cp, sr, out=out[1])
    out[1] += np.multiply(dpitch, cr, out=scratch)
    yaw_cp *= cr
    out[2] -= np.multiply(dpitch, sr, out=scratch)
    np.multiply(dyaw, sp, out=out[0])
    np.subtract(droll, out[0], out=out[0])
    return out


def _rotate(m: FloatArray, v: FloatArray) -> FloatArray:
    """Component-first m @ v: (3, 3, ...) and (3, ...) -> (3, ...)."""
    out = m[:, 0] * v[0]
    scratch = np.empty_like(out)
    out += np.multiply(m[:, 1], v[1], out=scratch)
    out += np.multiply(m[:, 2], v[2], out=scratch)
    return out


def _rows(x: FloatArray) -> FloatArray:
    """Component-first (3, n) -> the (n, 3) layout the outputs use."""
    return np.ascontiguousarray(x.T)


def _shift_coefficients(
    amp: FloatArray, omega: FloatArray, offsets: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Weights giving sum_k amp sin(w (t + d) + p) and its rate from [sin, cos](w t + p).

    sin(x + w d) = sin(x) cos(w d) + cos(x) sin(w d), and every sample shares the
    offsets d, so values at t + d are weighted sums of the terms at t: multiply-adds
    instead of libm calls. Returns (J, 3, 2K) value and rate weights.
    """
    wd = omega * offsets[:, None, None]
    a_cd, a_sd = amp * np.cos(wd), amp * np.sin(wd)
    value = np.concatenate([a_cd, a_sd], axis=-1)
    rate = np.concatenate([-a_sd * omega, a_cd * omega], axis=-1)
    return value, rate


def _combine(weights: FloatArray, features: FloatArray) -> FloatArray:
    """(3, 2K) weights . (3, 2K, n) features -> (3, n).

    einsum's own loop adds the terms in a fixed order, unlike BLAS, whose blocking
    (and so its rounding) depends on the batch size.
    """
    return np.einsum("ak,akn->an", weights, features)


class Motion:
    """Analytic trajectory of one simulated unit, sampled on demand at any device times.

    Attitude is roll, pitch, yaw, each a sum of sinusoids (plus a slow yaw drift, so yaw
    wraps); linear acceleration in the earth frame is a sum of sinusoids too. Pitch stays
    within +/-55 degrees so Euler angles never meet their singularity. A static config
    freezes the trajectory at t = 0. Internally arrays are component-first, (3, n),
    because NumPy is much faster on contiguous blocks than on length-3 rows.
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

        lin_weights = rng.uniform(0.2, 1.0, (3, _N_LINEAR_TERMS))
        lin_weights /= lin_weights.sum(axis=1, keepdims=True)
        self._lin_amp = max(cfg.linear_accel_amplitude_g, 0.0) * lin_weights
        self._lin_omega = 2.0 * np.pi * rng.uniform(_MIN_FREQ_HZ, _MAX_FREQ_HZ, lin_weights.shape)
        self._lin_phase = rng.uniform(0.0, 2.0 * np.pi, lin_weights.shape)

        code0 = round(float(celsius_to_mag_temperature_code(cfg.temperature_c)))
        others = code0 + rng.integers(-60, 61, 3)
        self._temperature = np.clip(np.concatenate([[code0], others]), 0, 4095).astype(np.uint16)

        if cfg.static:
            at_zero = np.sum(self._att_amp * np.sin(self._att_phase), axis=1)
            self._att_offset = self._att_offset + at_zero
            self._att_amp = np.zeros_like(self._att_amp)
            self._att_drift = np.zeros(3)
            self._lin_amp = np.zeros_like(self._lin_amp)

        self._earth_field = np.asarray(cfg.earth_field_gauss, dtype=np.float64)
        self._gyro_bias = np.asarray(cfg.gyro_bias_rad_s, dtype=np.float64)
        self._accel_bias = np.asarray(cfg.accel_bias_g, dtype=np.float64)
        self._max_euler_rate = float(
            np.max(
                np.sum(np.abs(self._att_amp * self._att_omega), axis=1) + np.abs(self._att_drift)
            )
        )
        # Sines of the Euler angles turn over at up to the Euler rate, on top of the
        # terms' own frequencies; this bounds how fast the quadrature integrands vary.
        max_omega = float(max(np.max(self._att_omega), np.max(self._lin_omega)))
        self._bandwidth_rad_s = 3.0 * self._max_euler_rate + 2.0 * max_omega

    def _features(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """[sin, cos] of every term's phase at t (n,): attitude (3, 2K, n), linear (3, 2L, n).

        Everything the trajectory yields at t, or at fixed offsets from t, is a weighted
        sum of these (see _shift_coefficients), so they are the only libm calls per term.
        """
        out = []
        for omega, phase in (
            (self._att_omega, self._att_phase),
            (self._lin_omega, self._lin_phase),
        ):
            arg = omega[..., None] * t + phase[..., None]
            k = omega.shape[1]
            features = np.empty((3, 2 * k, t.shape[0]))
            np.sin(arg, out=features[:, :k])
            np.cos(arg, out=features[:, k:])
            out.append(features)
        return out[0], out[1]

    def _euler(
        self, features: FloatArray, t: FloatArray, offset: float, weights: FloatArray
    ) -> FloatArray:
        """Unwrapped roll, pitch, yaw at t + offset, (3, n), given the offset's weights."""
        angles = _combine(weights, features)
        angles += self._att_offset[:, None]
        angles += self._att_drift[:, None] * (t + offset)
        return angles

    def euler_and_rates(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Unwrapped roll, pitch, yaw [rad] and their time derivatives, shape t.shape + (3,)."""
        tt = np.asarray(t, dtype=np.float64)
        flat = tt.reshape(-1)
        features, _ = self._features(flat)
        value, rate = _shift_coefficients(self._att_amp, self._att_omega, np.zeros(1))
        angles = self._euler(features, flat, 0.0, value[0])
        rates = _combine(rate[0], features) + self._att_drift[:, None]
        return angles.T.reshape((*tt.shape, 3)), rates.T.reshape((*tt.shape, 3))

    def linear_accel_earth(self, t: npt.ArrayLike) -> FloatArray:
        """Kinematic acceleration of the unit in the earth (NED) frame [g], shape t.shape + (3,)."""
        tt = np.asarray(t, dtype=np.float64)
        _, features = self._features(tt.reshape(-1))
        value, _ = _shift_coefficients(self._lin_amp, self._lin_omega, np.zeros(1))
        return _combine(value[0], features).T.reshape((*tt.shape, 3))

    def sample(self, t: npt.ArrayLike, period: float) -> dict[str, np.ndarray]:
        """Everything the unit can report at device times t [s], shape (n,).

        period is the output sample period [s]: DeltaAng and DeltaVel integrate over
        [t - period, t] by Gauss-Legendre quadrature, and C spans the last 1 ms
        calculation cycle. All arrays are float64 except temperature, which holds the
        uint16 A/D codes the device sends. Biases and noise affect only the sensor
        readings (accel, ang_rate, mag, deltas, raw codes), never M or C.
        """
        tt = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if tt.ndim != 1:
            raise ValueError(f"t must be one-dimensional, got shape {tt.shape}")
        if not period > 0.0:
            raise ValueError(f"period must be positive, got {period}")
        cfg = self.config
        n = tt.shape[0]

        # Offsets from t: now, one calculation cycle ago (for C), then quadrature nodes
        # in [-period, 0] with enough of them for the trajectory's bandwidth (never
        # fewer than five), which keeps the deltas float64-exact even for 1 s periods.
        half = 0.5 * period
        n_nodes = max(_MIN_GAUSS_NODES, -(-_series_order(self._bandwidth_rad_s * half) // 2))
        nodes, node_weights = _gauss_legendre(n_nodes)
        offsets = np.concatenate([[0.0, -CALCULATION_CYCLE_S], half * nodes - half])
        att_value, att_rate = _shift_coefficients(self._att_amp, self._att_omega, offsets)
        lin_value, _ = _shift_coefficients(self._lin_amp, self._lin_omega, offsets)
        att_features, lin_features = self._features(tt)

        euler0 = self._euler(att_features, tt, 0.0, att_value[0])
        m = euler_to_m(euler0.T)
        m_cf = m.transpose(1, 2, 0)
        m_prev = euler_to_m(self._euler(att_features, tt, offsets[1], att_value[1]).T)
        sin0, cos0 = np.sin(euler0), np.cos(euler0)

        # At the nodes, sin/cos of the Euler angles come from those at t by angle
        # addition over the (small, bounded) change, instead of more libm calls.
        step_bound = half * (1.0 - nodes[0]) * self._max_euler_rate
        delta_ang = np.zeros_like(euler0)
        delta_vel = np.zeros_like(euler0)
        for j in range(2, offsets.shape[0]):
            step = self._euler(att_features, tt, offsets[j], att_value[j])
            step -= euler0
            sin, cos = _sincos_near(sin0, cos0, step, step_bound)
            euler_rate = _combine(att_rate[j], att_features) + self._att_drift[:, None]
            lin = _combine(lin_value[j], lin_features) - _GRAVITY_NED_G[:, None]
            delta_ang += node_weights[j - 2] * _body_rate(sin, cos, euler_rate)
            delta_vel += node_weights[j - 2] * _euler_rotate(sin, cos, lin)
        delta_ang *= half
        delta_vel *= half
        delta_ang += (self._gyro_bias * period)[:, None]
        delta_vel += (self._accel_bias * period)[:, None]

        euler_rate0 = _combine(att_rate[0], att_features) + self._att_drift[:, None]
        ang_rate = _body_rate(sin0, cos0, euler_rate0) + self._gyro_bias[:, None]
        lin0 = _combine(lin_value[0], lin_features) - _GRAVITY_NED_G[:, None]
        accel = _rotate(m_cf, lin0) + self._accel_bias[:, None]
        stab_mag = _rotate(m_cf, self._earth_field)
        mag = stab_mag.copy()

        if cfg.noise_accel_g > 0.0 or cfg.noise_gyro_rad_s > 0.0 or cfg.noise_mag_gauss > 0.0:
            normals = _time_keyed_normals(cfg.seed, tt, 9)
            accel_noise = cfg.noise_accel_g * normals[0:3]
            gyro_noise = cfg.noise_gyro_rad_s * normals[3:6]
            accel += accel_noise
            ang_rate += gyro_noise
            mag += cfg.noise_mag_gauss * normals[6:9]
            delta_vel += accel_noise * period
            delta_ang += gyro_noise * period

        accel_rows, ang_rate_rows = _rows(accel), _rows(ang_rate)
        return {
            "m": m,
            "euler": m_to_euler(m),
            "quaternion": m_to_quaternion(m),
            "ang_rate": ang_rate_rows,
            "accel": accel_rows,
            "mag": _rows(mag),
            "stab_accel": -m[:, :, 2],
            "stab_mag": _rows(stab_mag),
            "delta_ang": _rows(delta_ang),
            "delta_vel": _rows(delta_vel),
            "c": m @ m_prev.transpose(0, 2, 1),
            "raw_accel": np.clip(
                RAW_ZERO_CODE + accel_rows * RAW_ACCEL_CODES_PER_G, 0.0, RAW_MAX_CODE
            ),
            "raw_ang_rate": np.clip(
                RAW_ZERO_CODE + ang_rate_rows * RAW_GYRO_CODES_PER_RAD_S, 0.0, RAW_MAX_CODE
            ),
            "temperature": np.tile(self._temperature, (n, 1)),
        }
