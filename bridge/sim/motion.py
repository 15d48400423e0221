"""Deterministic ground-truth motion of a simulated 3DM-GX3.

Every output comes from one analytic trajectory, so they agree (M, Euler and Q are one
attitude; AngRate is the body rate of M and DeltaAng its integral; Accel is the specific
force of the same motion) and tests can check a pipeline against exact values. A sample
is a pure function of (config, t), whatever batch it is in, so a unit can regenerate what
it sent (to the last float64 bit or so: NumPy's vector and scalar sin may round apart).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Collection
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from bridge.protocol import convert
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.protocol.table import CALCULATION_CYCLE_S

FloatArray = npt.NDArray[np.float64]

RAW_ZERO_CODE = 65536.0
RAW_MAX_CODE = 131071.0
RAW_ACCEL_CODES_PER_G = 8000.0
RAW_GYRO_CODES_PER_RAD_S = 3000.0

_MAX_PITCH_AMPLITUDE_RAD = math.radians(55.0)  # keeps Euler angles clear of gimbal lock
_GRAVITY_NED_G = np.array([0.0, 0.0, 1.0])
# Gauss-Legendre nodes in [-1, 1] and weights; cached, as leggauss costs more than a batch.
_gauss_legendre = functools.cache(np.polynomial.legendre.leggauss)
#: Seconds between the knots of the bias random walk, which is linear between them: far
#: below the averaging times at which a random walk shows in an Allan deviation.
WALK_KNOT_S = 1.0
_WALK_SALT = 0x5EED_7A1C_0FF5_E7B1  # keys the walk's normals apart from the white noise's


@dataclass(frozen=True)
class MotionConfig:
    """What a simulated unit experiences; the seed fixes the trajectory and the noise.

    static freezes the seed's attitude (zero rate, gravity-only accel). The biases are
    the sensor's own true offsets, added to what it reports, so that a stationary bias
    capture (0xCD) has something to find. Noise is white Gaussian, zero by default:
    noise_accel_g and noise_gyro_rad_s per 1 ms calculation cycle (the unit's filter
    averages it down), or, in Kalibr's continuous-time units (what ``gx3 allan`` reads
    off), a white noise density (m/s²/√Hz, rad/s/√Hz: each output sample's noise is the
    density over the square root of its period) and a bias random walk (m/s³/√Hz,
    rad/s²/√Hz: the bias wanders from zero at t = 0 as a Wiener process, linear between
    knots WALK_KNOT_S apart).
    earth_field_gauss is north-east-down. The magnetometer sits among hard and soft iron:
    it reads soft_iron @ true + hard_iron (soft_iron row-major), what a host-side iron
    calibration has to undo. spin_rad_s adds steady roll and yaw turns to the sway, so a
    unit can turn on a turntable or (``tumbling``) through every orientation. band_hz
    bounds the sway's frequencies (``handheld``: a hand's brisker turns). With a
    mounting the unit sits on a body it shares with others: the sway is the body's
    (its seed, not the unit's), and the unit sees it through its own mounting.
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
    accelerometer_noise_density: float = 0.0
    accelerometer_random_walk: float = 0.0
    gyroscope_noise_density: float = 0.0
    gyroscope_random_walk: float = 0.0
    temperature_c: float = 25.0
    hard_iron_gauss: tuple[float, float, float] = (0.0, 0.0, 0.0)
    soft_iron: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    spin_rad_s: tuple[float, float] = (0.0, 0.0)
    band_hz: tuple[float, float] = (0.05, 0.5)
    mounting: Mounting | None = None


@dataclass(frozen=True)
class Mounting:
    """Where a unit sits on a rigid body that several units share.

    The body's motion comes from ``body_seed`` and the rest of the unit's MotionConfig
    (give co-mounted units the same), as a function of host seconds since power-up, so
    units that power up together see one motion whatever their clocks. The unit's axes
    are turned against the body's by ``rotation`` (row-major, v_unit = rotation @
    v_body), and it sits ``lever_arm_m`` from the body's origin (body axes, metres):
    its accelerometer feels the origin's specific force plus alpha x r + omega x
    (omega x r), with omega and alpha the body's rate and angular acceleration.

    Raises:
        ValueError: ``rotation`` is not a proper rotation (orthonormal, determinant +1).
    """

    body_seed: int = 0
    rotation: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        r = np.reshape(np.asarray(self.rotation, np.float64), (3, 3))
        if not (np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
            raise ValueError("mounting: rotation must be a proper rotation matrix, "
                             "row-major (orthonormal, determinant +1)")

    @property
    def matrix(self) -> FloatArray:
        """The rotation, body to unit, (3, 3)."""
        return np.reshape(np.asarray(self.rotation, np.float64), (3, 3))

    @classmethod
    def turned(cls, roll_pitch_yaw_deg: tuple[float, float, float],
               lever_arm_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
               body_seed: int = 0) -> Mounting:
        """A mounting given as the unit's axes' roll, pitch and yaw against the body's.

        As a unit's attitude against north-east-down: yaw, then pitch, then roll (ZYX).

        Args:
            roll_pitch_yaw_deg: The angles, degrees.
            lever_arm_m: Where the unit sits from the body's origin (body axes, metres).
            body_seed: The body's seed.

        Returns:
            The mounting.
        """
        rotation = convert.euler_to_m(np.radians(roll_pitch_yaw_deg))
        return cls(body_seed, tuple(rotation.ravel().tolist()), lever_arm_m)


def handheld(config: MotionConfig, mounting: Mounting | None = None) -> MotionConfig:
    """``config`` turned by hand: brisk turns about all three axes, as to align units.

    Sways of 0.4 rad (yaw 0.8) at 0.15-0.8 Hz, rates of a few rad/s and angular
    accelerations of up to ~10 rad/s², with 0.3 g of linear acceleration: what turning a
    rig by hand for a minute gives, within a GX3's 300 deg/s and 5 g.

    Args:
        config: The motion to turn.
        mounting: Where the unit sits on the body; None: as the config has it.

    Returns:
        The config, its amplitudes, band and mounting changed.
    """
    return replace(config, attitude_amplitude_rad=0.4, linear_accel_amplitude_g=0.3,
                   band_hz=(0.15, 0.8), mounting=mounting or config.mounting)


def tumbling(config: MotionConfig) -> MotionConfig:
    """``config`` turned through every orientation: the motion an iron calibration needs.

    Roll and yaw keep turning (at incommensurate rates) while pitch swings to its +/-55
    degrees.

    Args:
        config: The motion to turn.

    Returns:
        The config, its attitude amplitude and spin changed.
    """
    return replace(config, attitude_amplitude_rad=1.0, spin_rad_s=(0.7, 0.45))


def _splitmix64(x: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    """SplitMix64: a well-mixed 64-bit hash that NumPy applies to whole arrays."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _sinusoids(rng: np.random.Generator, axis_amp: FloatArray, k: int,
               band_hz: tuple[float, float]) -> tuple[FloatArray, ...]:
    """Amplitudes, angular frequencies and phases, (3, k) each, of k terms per axis."""
    share = rng.uniform(0.2, 1.0, (3, k))
    amp = axis_amp[:, None] * (share / share.sum(axis=1, keepdims=True))
    return (amp, 2.0 * np.pi * rng.uniform(*band_hz, (3, k)),
            rng.uniform(0.0, 2.0 * np.pi, (3, k)))


def _time_keyed_normals(seed: int, t: FloatArray, count: int) -> FloatArray:
    """(n, count) standard normals that depend only on (seed, t rounded to 1 us).

    Hashing the time stamp, not drawing from a generator, makes a sample's noise
    independent of its batch; Box-Muller turns the hashed uniforms into normals.
    """
    micros = np.round(t * 1e6).astype(np.int64).view(np.uint64)
    key = _splitmix64(np.array([seed & 0xFFFF_FFFF_FFFF_FFFF], dtype=np.uint64))
    pairs = (count + 1) // 2
    streams = np.arange(1, 2 * pairs + 1, dtype=np.uint64) * np.uint64(0xD1B54A32D192ED03)
    bits = _splitmix64(streams ^ _splitmix64(micros ^ key)[:, None])
    u = ((bits >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0**-53  # uniform in (0, 1)
    radius, angle = np.sqrt(-2.0 * np.log(u[:, :pairs])), 2.0 * np.pi * u[:, pairs:]
    return np.concatenate([radius * np.cos(angle), radius * np.sin(angle)], axis=1)[:, :count]


def _times(t: npt.ArrayLike) -> FloatArray:
    times: FloatArray = np.atleast_1d(np.asarray(t, dtype=np.float64))
    if times.ndim != 1:
        raise ValueError(f"t must be one-dimensional, got shape {times.shape}")
    return times


class Motion:
    """Analytic trajectory of one simulated unit, sampled on demand at any device times.

    Roll, pitch and yaw are each a sum of three sinusoids (yaw also drifts slowly, so it
    wraps); the earth-frame linear acceleration is a sum of two per axis. Pitch stays
    within +/-55 degrees, clear of the Euler singularity. static freezes the t = 0 pose.
    A mounted unit (``Mounting``) sees that motion as its body's, through its mounting.
    Sums over terms use einsum: one pass, in an order that does not depend on the batch.

    Args:
        config: What the unit experiences; None: the default motion.
    """

    def __init__(self, config: MotionConfig | None = None) -> None:
        self.config = cfg = config if config is not None else MotionConfig()
        mounting = cfg.mounting
        rng = np.random.default_rng(cfg.seed if mounting is None else mounting.body_seed)
        # The draws and their order define each seed's trajectory: keep them stable.
        amplitude = max(cfg.attitude_amplitude_rad, 0.0)
        axis_amp = np.array([amplitude, min(amplitude, _MAX_PITCH_AMPLITUDE_RAD), 2 * amplitude])
        self._att_amp, self._att_omega, self._att_phase = _sinusoids(rng, axis_amp, 3,
                                                                     cfg.band_hz)
        self._att_offset = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
        yaw_drift_rad_s = rng.uniform(-1.0, 1.0) * 0.25 * amplitude
        self._att_drift = np.array([0.0, 0.0, yaw_drift_rad_s])

        lin_amp = np.full(3, max(cfg.linear_accel_amplitude_g, 0.0))
        self._lin_amp, self._lin_omega, self._lin_phase = _sinusoids(rng, lin_amp, 2,
                                                                     cfg.band_hz)

        code0 = round(float(convert.celsius_to_mag_temperature_code(cfg.temperature_c)))
        codes = np.concatenate([[code0], code0 + rng.integers(-60, 61, 3)])
        self._temperature = np.clip(codes, 0, 4095).astype(np.uint16)

        self._att_drift += np.array([cfg.spin_rad_s[0], 0.0, cfg.spin_rad_s[1]])
        if cfg.static:
            self._att_offset = self.euler_and_rates(0.0)[0]
            self._att_amp = np.zeros_like(self._att_amp)
            self._att_drift = np.zeros(3)
            self._lin_amp = np.zeros_like(self._lin_amp)
        # The quadrature integrands hold sin/cos of the Euler angles, which turn at up to
        # the peak Euler rate on top of the terms' own frequencies: a bound on bandwidth.
        euler_rate = np.abs(self._att_amp * self._att_omega).sum(axis=1) + np.abs(self._att_drift)
        max_omega = max(self._att_omega.max(), self._lin_omega.max())
        self._bandwidth_rad_s = float(3.0 * euler_rate.max() + 2.0 * max_omega)
        # accel then gyro, per sqrt(s) of a knot interval; the walk's knots so far
        self._walk_sigma = np.repeat([cfg.accelerometer_random_walk / STANDARD_GRAVITY,
                                      cfg.gyroscope_random_walk], 3) * math.sqrt(WALK_KNOT_S)
        self._walk_knots = np.zeros((1, 6))
        self._mount = None if mounting is None else (
            mounting.matrix, np.asarray(mounting.lever_arm_m, np.float64))

    def euler_and_rates(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Unwrapped roll, pitch, yaw [rad] and their time derivatives.

        Args:
            t: Device times [s].

        Returns:
            (Euler angles, their rates [rad/s]), shape t.shape + (3,) each.
        """
        t = np.asarray(t, dtype=np.float64)[..., None]
        phase = self._att_phase + self._att_omega * t[..., None]
        euler = np.einsum("ak,...ak->...a", self._att_amp, np.sin(phase))
        rates = np.einsum("ak,...ak->...a", self._att_amp * self._att_omega, np.cos(phase))
        return euler + self._att_offset + self._att_drift * t, rates + self._att_drift

    def linear_accel_earth(self, t: npt.ArrayLike) -> FloatArray:
        """Kinematic acceleration of the unit in the earth (NED) frame [g].

        Args:
            t: Device times [s].

        Returns:
            The acceleration, shape t.shape + (3,).
        """
        phase = self._lin_phase + self._lin_omega * np.asarray(t, dtype=np.float64)[..., None, None]
        accel: FloatArray = np.einsum("ak,...ak->...a", self._lin_amp, np.sin(phase))
        return accel

    def _euler_accelerations(self, t: FloatArray) -> FloatArray:
        """Second time derivatives of roll, pitch and yaw [rad/s²], (n, 3)."""
        phase = self._att_phase + self._att_omega * t[:, None, None]
        accel: FloatArray = -np.einsum("ak,nak->na", self._att_amp * self._att_omega ** 2,
                                       np.sin(phase))
        return accel

    def _attitude(self, t: FloatArray) -> FloatArray:
        """The unit's true M at times t, through its mounting, (n, 3, 3)."""
        m = convert.euler_to_m(self.euler_and_rates(t)[0])
        return m if self._mount is None else self._mount[0] @ m

    def _kinematics(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """True M, body rate [rad/s] and specific force [g] at times t, shape (n,).

        A mounted unit's: the body's turned by its mounting, the force at its lever arm.
        """
        euler, euler_rate = self.euler_and_rates(t)
        droll, dpitch, dyaw = euler_rate.T
        m = convert.euler_to_m(euler)
        # ZYX kinematics in the sensor frame: roll turns about x, pitch about the rolled y
        # axis (0, cos roll, -sin roll) and yaw about earth z, which is M's third column.
        roll = euler[:, 0]
        cos, sin = np.cos(roll), np.sin(roll)
        body_rate = np.stack([droll, dpitch * cos, -dpitch * sin], axis=1)
        body_rate = body_rate + dyaw[:, None] * m[:, :, 2]
        lin = self.linear_accel_earth(t) - _GRAVITY_NED_G
        force = np.einsum("nij,nj->ni", m, lin)
        if self._mount is None:
            return m, body_rate, force
        rotation, arm = self._mount
        # The body rate's derivative, term by term; M's third column turns as
        # d/dt M[:, 2] = -omega x M[:, 2], since dM/dt = -[omega]x M.
        ddroll, ddpitch, ddyaw = self._euler_accelerations(t).T
        alpha = np.stack([ddroll, ddpitch * cos - dpitch * droll * sin,
                          -ddpitch * sin - dpitch * droll * cos], axis=1)
        alpha += ddyaw[:, None] * m[:, :, 2] - dyaw[:, None] * np.cross(body_rate, m[:, :, 2])
        lever = np.cross(alpha, arm) + np.cross(body_rate, np.cross(body_rate, arm))
        force = force + lever / STANDARD_GRAVITY
        return rotation @ m, body_rate @ rotation.T, force @ rotation.T

    def _node_count(self, half_period: float) -> int:
        """Gauss-Legendre nodes (at least 5) for float64-exact deltas at any period.

        n nodes are exact to degree 2n - 1, so bandwidth B over half-width h errs by
        ~(Bh)^2n / (2n)!.
        """
        log_bh = math.log(max(self._bandwidth_rad_s * half_period, 1e-300))
        n = 5
        while 2 * n * log_bh - math.lgamma(2 * n + 1) > math.log(1e-17):
            n += 1
        return n

    def _noise(self, t: FloatArray, gain: tuple[float, float, float],
               period: float = math.inf) -> FloatArray:
        """(n, 9) accel, gyro and mag noise at t.

        Each per-cycle sigma times its gain, with the white noise density over the
        square root of the output ``period`` added in quadrature (the same normals: zero
        densities leave the noise, and so the emulator's bytes, as they were).
        """
        cfg = self.config
        root = math.sqrt(period)
        sigma = np.repeat([
            math.hypot(cfg.noise_accel_g * gain[0],
                       cfg.accelerometer_noise_density / STANDARD_GRAVITY / root),
            math.hypot(cfg.noise_gyro_rad_s * gain[1], cfg.gyroscope_noise_density / root),
            cfg.noise_mag_gauss * gain[2]], 3)
        return sigma * _time_keyed_normals(cfg.seed, t, 9) if sigma.any() else np.zeros((1, 9))

    def bias_walk(self, t: npt.ArrayLike) -> FloatArray:
        """The accel [g] and gyro [rad/s] bias random walk at device times ``t``.

        A pure function of (config, t): the knots are cumulative sums of normals keyed
        by their index, kept as far as any time asked for so far, so that a batch costs
        only its own knots.

        Args:
            t: Device times [s], shape (n,).

        Returns:
            (n, 6): accel x, y, z then gyro x, y, z; zero at and before t = 0.
        """
        t = _times(t)
        if not self._walk_sigma.any():
            return np.zeros((len(t), 6))
        at = np.clip(t, 0.0, None) / WALK_KNOT_S
        need = math.floor(float(at.max(initial=0.0))) + 2
        have = len(self._walk_knots)
        if need > have:
            index = np.arange(have, need, dtype=np.float64)
            steps = self._walk_sigma * _time_keyed_normals(
                self.config.seed ^ _WALK_SALT, index, 6)
            self._walk_knots = np.concatenate(
                [self._walk_knots, self._walk_knots[-1] + np.cumsum(steps, axis=0)])
        whole = np.floor(at).astype(np.int64)
        frac = (at - whole)[:, None]
        walk: FloatArray = (self._walk_knots[whole] * (1.0 - frac)
                            + self._walk_knots[whole + 1] * frac)
        return walk

    def magnetometer(self, t: npt.ArrayLike, gain: float = 1.0) -> FloatArray:
        """The mag reading alone: what ``sample`` gives, at less cost.

        Args:
            t: Device times [s], shape (n,).
            gain: Scales the magnetometer noise (a filter averaging M samples: 1/sqrt(M)).

        Returns:
            The readings [gauss], (n, 3), sensor frame.
        """
        t = _times(t)
        m = self._attitude(t)
        field = self._ironed(m @ np.asarray(self.config.earth_field_gauss, dtype=np.float64))
        noise: FloatArray = self._noise(t, (0.0, 0.0, gain))[:, 6:9]
        return field + noise

    def _ironed(self, field: FloatArray) -> FloatArray:
        """The true body-frame field as the magnetometer reads it among the unit's iron."""
        soft = np.asarray(self.config.soft_iron, dtype=np.float64).reshape(3, 3)
        out: FloatArray = field @ soft.T + np.asarray(self.config.hard_iron_gauss)
        return out

    def sample(self, t: npt.ArrayLike, period: float,
               noise_gain: tuple[float, float, float] = (1.0, 1.0, 1.0),
               only: Collection[str] | None = None) -> dict[str, np.ndarray]:
        """Everything the unit can report at device times ``t``.

        DeltaAng and DeltaVel integrate over [t - period, t] by Gauss-Legendre
        quadrature, and C spans the last 1 ms calculation cycle. Biases and noise affect
        only the sensor readings (accel, ang_rate, mag, deltas, raw codes), never M or C.

        Args:
            t: Device times [s], shape (n,).
            period: The output sample period [s].
            noise_gain: Scales the accel, gyro and mag noise (a filter averaging M
                samples: 1/sqrt(M)).
            only: At least these quantities: DeltaAng and DeltaVel's quadrature and C's
                previous orientation, most of the cost, are computed only when asked
                for (every value is the same either way); None: everything.

        Returns:
            Quantity name -> values, (n, ...): float64, except temperature, which holds
            the uint16 A/D codes the device sends.

        Raises:
            ValueError: ``t`` is not one-dimensional, or ``period`` is not positive.
        """
        t = _times(t)
        if not period > 0.0:
            raise ValueError(f"period must be positive, got {period}")
        cfg = self.config
        gyro_bias, accel_bias = np.asarray(cfg.gyro_bias_rad_s), np.asarray(cfg.accel_bias_g)

        m, rate, force = self._kinematics(t)
        stab_mag = m @ np.asarray(cfg.earth_field_gauss, dtype=np.float64)

        stab_mag = self._ironed(stab_mag)
        noise = self._noise(t, noise_gain, period)
        if self._walk_sigma.any():
            noise = noise + np.pad(self.bias_walk(t), ((0, 0), (0, 3)))
        accel = force + accel_bias + noise[:, 0:3]
        ang_rate = rate + gyro_bias + noise[:, 3:6]
        out: dict[str, np.ndarray] = {}
        if only is None or "delta_ang" in only or "delta_vel" in only:
            # Gauss-Legendre quadrature over [t - period, t] of the biased rate and force
            half = 0.5 * period
            nodes, weights = _gauss_legendre(self._node_count(half))
            delta_ang, delta_vel = gyro_bias * period, accel_bias * period
            for node, weight in zip(nodes, weights, strict=True):
                _, node_rate, node_force = self._kinematics(t + half * (node - 1.0))
                delta_ang = delta_ang + half * weight * node_rate
                delta_vel = delta_vel + half * weight * node_force
            out["delta_ang"] = delta_ang + noise[:, 3:6] * period
            out["delta_vel"] = delta_vel + noise[:, 0:3] * period
        if only is None or "c" in only:
            m_prev = self._attitude(t - CALCULATION_CYCLE_S)
            out["c"] = m @ m_prev.swapaxes(1, 2)
        return out | {
            "m": m,
            "euler": convert.m_to_euler(m),
            "quaternion": convert.m_to_quaternion(m),
            "ang_rate": ang_rate,
            "accel": accel,
            "mag": stab_mag + noise[:, 6:9],
            "stab_accel": -m[:, :, 2],
            "stab_mag": stab_mag,
            "raw_accel": np.clip(RAW_ZERO_CODE + accel * RAW_ACCEL_CODES_PER_G, 0, RAW_MAX_CODE),
            "raw_ang_rate": np.clip(
                RAW_ZERO_CODE + ang_rate * RAW_GYRO_CODES_PER_RAD_S, 0, RAW_MAX_CODE
            ),
            "temperature": np.tile(self._temperature, (t.shape[0], 1)),
        }
