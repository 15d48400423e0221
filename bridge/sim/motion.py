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
from collections.abc import Callable, Collection
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
#: Calculation cycles a second: the rate of the samples the fixed first filter stage gives.
CYCLES_PER_S = round(1.0 / CALCULATION_CYCLE_S)
_WALK_SALT = 0x5EED_7A1C_0FF5_E7B1  # keys the walk's normals apart from the white noise's
_MAG_SALT = 0x3A61_C0DE_9E37_79B9  # and the magnetometer's from the accel and gyro's
_MASK64 = (1 << 64) - 1
#: Indexes (calculation cycles, walk knots) whose normals one generator draws at once.
NORMALS_BLOCK = 1024
#: The instantaneous accel and gyro readings, computed when any of them is asked for.
_POINT_READINGS = frozenset({"accel", "ang_rate", "raw_accel", "raw_ang_rate"})


@dataclass(frozen=True)
class SignalChain:
    """What a unit does to its sensors' signals before it sends them (the manual's Filtering).

    Noise and the bias random walk enter at the sensor. The fixed first stage, a 30 kHz
    30-tap moving average read once a 1 ms calculation cycle, gives each cycle the mean
    of that cycle's 30 sensor samples: for white noise of density N, one normal of
    variance N² · 1000 Hz a cycle, independent from cycle to cycle, which is exactly
    what 30 normals averaged give (so the emulator draws that one). The second stage
    averages the last ``filter_width`` (M) cycles' samples; a record every D cycles (the
    decimation) sends the newest average. The motion's slow signal passes the moving
    average as its exact group delay, (M - 1)/2 cycles (Equation 2's gain,
    ``convert.fir_response``, is 1 within 5e-4 at its <= 0.5 Hz and 1.1e-3 at a hand's
    <= 0.8 Hz, ``handheld``, for any width up to 32), and so does the bias walk, linear
    between knots 1 s apart; the noise is averaged sample by sample. The magnetometer's
    chain is the same with its own width Mm. The analog anti-alias filters ahead of the
    ADC (226 Hz and up, Table 6) are not modelled: they change nothing at the averaging
    times a noise figure is read at.

    DeltaAngle and DeltaVelocity sum the filtered 1 kHz rates and accelerations of the
    D cycles of their period (each cycle's sample is the first stage's mean over that
    cycle, so the signal's part is the exact integral over the period). With coning and
    sculling (0xDB flag bit 1, "Full 1kHz Coning and Sculling integration"), the sum is
    corrected as a strapdown integration at 1 kHz corrects it: DeltaAngle becomes the
    rotation vector of the attitude change over the period, not the integral of the
    rate, and DeltaVelocity the integral of the specific force carried into the body
    frame at the period's start. The manual names the corrections but not their
    algorithm; these are what a 1 kHz integration converges to.

    Attributes:
        filter_width: M, the accel and gyro moving average's width (0xDB, 1 to 32).
        mag_filter_width: Mm, the magnetometer's (0xDB, 1 to 32).
        coning_sculling: Whether DeltaAngle and DeltaVelocity are corrected for coning
            and sculling (0xDB flag bit 1).
    """

    filter_width: int = 1
    mag_filter_width: int = 1
    coning_sculling: bool = False

    def delays(self) -> tuple[float, float]:
        """Seconds by which the moving averages delay the slow signal: (M-1)/2 cycles.

        Returns:
            (accel and gyro delay, magnetometer delay), seconds.
        """
        return ((self.filter_width - 1) / 2 * CALCULATION_CYCLE_S,
                (self.mag_filter_width - 1) / 2 * CALCULATION_CYCLE_S)


#: A bare sensor: no moving average, deltas the plain integral (what ``Motion`` gives
#: unless a unit's chain is asked for).
SENSOR = SignalChain()


@dataclass(frozen=True)
class MotionConfig:
    """What a simulated unit experiences; the seed fixes the trajectory and the noise.

    static freezes the seed's attitude (zero rate, gravity-only accel). The biases are
    the sensor's own true offsets, added to what it reports, so that a stationary bias
    capture (0xCD) has something to find. Noise is white Gaussian at the sensor, zero by
    default, and reaches the records through the unit's filters (``SignalChain``):
    noise_accel_g, noise_gyro_rad_s and noise_mag_gauss are the spread of one 1 ms
    calculation cycle's sample before the moving average of M; the densities are in
    Kalibr's continuous-time units (what ``gx3 allan`` reads off): a white noise
    density (m/s²/√Hz, rad/s/√Hz) and a bias random walk (m/s³/√Hz, rad/s²/√Hz: the bias
    wanders from zero at t = 0 as a Wiener process, linear between knots WALK_KNOT_S
    apart).
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


def _sinusoids(rng: np.random.Generator, axis_amp: FloatArray, k: int,
               band_hz: tuple[float, float]) -> tuple[FloatArray, ...]:
    """Amplitudes, angular frequencies and phases, (3, k) each, of k terms per axis."""
    share = rng.uniform(0.2, 1.0, (3, k))
    amp = axis_amp[:, None] * (share / share.sum(axis=1, keepdims=True))
    return (amp, 2.0 * np.pi * rng.uniform(*band_hz, (3, k)),
            rng.uniform(0.0, 2.0 * np.pi, (3, k)))


class _KeyedNormals:
    """Standard normals, ``count`` per integer index, that depend only on (seed, index).

    Drawn ``NORMALS_BLOCK`` indexes at a time by a generator seeded with (seed, block),
    not from one stream, so an index's normals are the same whatever batch asks for
    them, at the cost of a generator a block; the last few blocks are kept, since the
    batches of a stream share them.

    Args:
        seed: Keys the normals.
        count: Normals per index.
    """

    _KEPT = 8

    def __init__(self, seed: int, count: int) -> None:
        self.seed, self.count = seed & _MASK64, count
        self._blocks: dict[int, FloatArray] = {}

    def _block(self, block: int) -> FloatArray:
        if block not in self._blocks:
            if len(self._blocks) >= self._KEPT:
                del self._blocks[next(iter(self._blocks))]
            generator = np.random.Generator(np.random.PCG64(
                np.random.SeedSequence([self.seed, block & _MASK64])))
            self._blocks[block] = generator.standard_normal((NORMALS_BLOCK, self.count))
        return self._blocks[block]

    def __call__(self, index: npt.NDArray[np.int64]) -> FloatArray:
        """(n, count) normals of the indexes ``index``."""
        blocks = index // NORMALS_BLOCK
        drawn, where = np.unique(blocks, return_inverse=True)
        table = np.concatenate([self._block(b) for b in drawn.tolist()])
        out: FloatArray = table[where * NORMALS_BLOCK + index % NORMALS_BLOCK]
        return out


def _averaged_normals(normals: _KeyedNormals, cycles: npt.NDArray[np.int64],
                      weights: FloatArray) -> FloatArray:
    """Per cycle k: the cycles up to k, (k - W, k], weighted: sum_i weights[i] z[k - W + 1 + i].

    z are ``normals`` per cycle, so the result is a pure function of (seed, k). Where the
    windows overlap, each cycle's normals are taken once for all of them; apart (a
    decimation past the width), only the windows' are.

    Returns:
        (n, count).
    """
    width = len(weights)
    first, last = int(cycles.min()) + 1 - width, int(cycles.max())
    if last - first + 1 <= len(cycles) * width:
        z = normals(np.arange(first, last + 1, dtype=np.int64))
        windows = np.lib.stride_tricks.sliding_window_view(z, width, axis=0)[cycles + 1 - width
                                                                               - first]
    else:
        index = (cycles[:, None] + np.arange(1 - width, 1, dtype=np.int64)).reshape(-1)
        windows = normals(index).reshape(len(cycles), width, normals.count).swapaxes(1, 2)
    out: FloatArray = np.einsum("ncw,w->nc", windows, weights)  # not BLAS: no threads
    return out


def _cycles(t: FloatArray) -> npt.NDArray[np.int64]:
    """The calculation cycles nearest device times ``t``: what keys their noise."""
    return np.round(t * CYCLES_PER_S).astype(np.int64)


def _rotation_vector(r: FloatArray) -> FloatArray:
    """(n, 3) rotation vectors (axis times angle, up to pi) of (n, 3, 3) rotations.

    From the skew part, sin(angle) times the axis, and the trace, stable at small angles.
    """
    skew = 0.5 * np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                           r[:, 1, 0] - r[:, 0, 1]], axis=1)
    sine = np.linalg.norm(skew, axis=1)
    angle = np.arctan2(sine, 0.5 * (np.trace(r, axis1=1, axis2=2) - 1.0))
    scale = np.divide(angle, sine, out=np.ones_like(angle), where=sine > 0.0)
    out: FloatArray = skew * scale[:, None]
    return out


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
        body_time: Maps the device seconds ``sample`` and ``magnetometer`` take to the
            seconds the motion runs on: a body several units share moves in host seconds
            since power-up, while each unit's cycles, its filter's delay and its noise
            keep its own clock's. None: the same seconds.
    """

    def __init__(self, config: MotionConfig | None = None,
                 body_time: Callable[[FloatArray], FloatArray] | None = None) -> None:
        self.config = cfg = config if config is not None else MotionConfig()
        self._body_time = body_time
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
        # the spread of one calculation cycle's sample, after the first filter stage:
        # accel [g], gyro [rad/s], mag [gauss], 3 each
        root = math.sqrt(CYCLES_PER_S)
        self._cycle_sigma = np.repeat([
            math.hypot(cfg.noise_accel_g,
                       cfg.accelerometer_noise_density / STANDARD_GRAVITY * root),
            math.hypot(cfg.noise_gyro_rad_s, cfg.gyroscope_noise_density * root),
            cfg.noise_mag_gauss], 3)
        self._cycle_normals = _KeyedNormals(cfg.seed, 6)
        self._mag_normals = _KeyedNormals(cfg.seed ^ _MAG_SALT, 3)
        self._knot_normals = _KeyedNormals(cfg.seed ^ _WALK_SALT, 6)
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
        """The unit's true M at device times t, through its mounting, (n, 3, 3)."""
        if self._body_time is not None:
            t = self._body_time(t)
        m = convert.euler_to_m(self.euler_and_rates(t)[0])
        return m if self._mount is None else self._mount[0] @ m

    def _kinematics(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """True M, body rate [rad/s] and specific force [g] at device times t, shape (n,).

        A mounted unit's: the body's turned by its mounting, the force at its lever arm.
        """
        if self._body_time is not None:
            t = self._body_time(t)
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

    def _chain_noise(self, cycles: npt.NDArray[np.int64], width: int, span: int = 0,
                     mag: bool = False) -> FloatArray:
        """The white noise a chain's moving average of ``width`` leaves at ``cycles``.

        span 0: each cycle's average, what a sample reports (accel and gyro: (n, 6); with
        ``mag`` the magnetometer's, (n, 3)); span D: the sum of the averages of the D
        cycles up to each, times the cycle, what a delta over D cycles adds (n, 6).
        """
        sigma = self._cycle_sigma[6:9] if mag else self._cycle_sigma[0:6]
        if not sigma.any():
            return np.zeros((len(cycles), len(sigma)))
        weights = np.full(width, 1.0 / width)
        if span:
            weights = np.convolve(np.ones(span), weights) * CALCULATION_CYCLE_S
        normals = self._mag_normals if mag else self._cycle_normals
        noise: FloatArray = sigma * _averaged_normals(normals, cycles, weights)
        return noise

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
            index = np.arange(have, need, dtype=np.int64)
            steps = self._walk_sigma * self._knot_normals(index)
            self._walk_knots = np.concatenate(
                [self._walk_knots, self._walk_knots[-1] + np.cumsum(steps, axis=0)])
        whole = np.floor(at).astype(np.int64)
        frac = (at - whole)[:, None]
        walk: FloatArray = (self._walk_knots[whole] * (1.0 - frac)
                            + self._walk_knots[whole + 1] * frac)
        return walk

    def magnetometer(self, t: npt.ArrayLike, chain: SignalChain = SENSOR) -> FloatArray:
        """The mag reading alone: what ``sample`` gives, at less cost.

        Args:
            t: Device times of the calculation cycles the readings are sent at [s], (n,).
            chain: The unit's filters (its mag moving average delays and averages).

        Returns:
            The readings [gauss], (n, 3), sensor frame.
        """
        t = _times(t)
        m = self._attitude(t - chain.delays()[1])
        field = self._ironed(m @ np.asarray(self.config.earth_field_gauss, dtype=np.float64))
        return field + self._chain_noise(_cycles(t), chain.mag_filter_width, mag=True)

    def _ironed(self, field: FloatArray) -> FloatArray:
        """The true body-frame field as the magnetometer reads it among the unit's iron."""
        soft = np.asarray(self.config.soft_iron, dtype=np.float64).reshape(3, 3)
        out: FloatArray = field @ soft.T + np.asarray(self.config.hard_iron_gauss)
        return out

    def _deltas(self, seen: FloatArray, m: FloatArray, cycles: npt.NDArray[np.int64],
                period: float, chain: SignalChain) -> tuple[FloatArray, FloatArray]:
        """DeltaAng and DeltaVel over the ``period`` up to each instant ``seen``.

        The signal by Gauss-Legendre quadrature over [seen - period, seen] (``m``: the
        attitude at ``seen``), with the chain's coning and sculling; the biases and the
        walk at the period's middle times the period; the chain's noise summed over the
        period's cycles.
        """
        cfg = self.config
        half = 0.5 * period
        nodes, weights = _gauss_legendre(self._node_count(half))
        delta_ang = np.asarray(cfg.gyro_bias_rad_s) * period
        delta_vel = np.asarray(cfg.accel_bias_g) * period
        start = self._attitude(seen - period) if chain.coning_sculling else None
        turned, pushed = np.zeros((len(seen), 3)), np.zeros((len(seen), 3))
        for node, weight in zip(nodes, weights, strict=True):
            node_m, node_rate, node_force = self._kinematics(seen + half * (node - 1.0))
            if start is None:
                turned = turned + half * weight * node_rate
            else:  # sculling: summed in the earth frame, then turned into the start's
                node_force = np.einsum("nji,nj->ni", node_m, node_force)
            pushed = pushed + half * weight * node_force
        if start is not None:  # coning: the rotation vector of the attitude change
            turned = _rotation_vector(start @ m.swapaxes(1, 2))
            pushed = np.einsum("nij,nj->ni", start, pushed)
        delta_ang, delta_vel = delta_ang + turned, delta_vel + pushed
        noise = self._chain_noise(cycles, chain.filter_width,
                                  max(1, round(period * CYCLES_PER_S)))
        if self._walk_sigma.any():
            noise = noise + self.bias_walk(seen - half) * period
        return delta_ang + noise[:, 3:6], delta_vel + noise[:, 0:3]

    def sample(self, t: npt.ArrayLike, period: float, chain: SignalChain = SENSOR,
               only: Collection[str] | None = None) -> dict[str, np.ndarray]:
        """Everything the unit can report at the calculation cycles at device times ``t``.

        Values pass the unit's ``chain``: the signal describes the instant its filter
        delay before ``t``, the noise is averaged cycle by cycle (``SignalChain``), and
        DeltaAng and DeltaVel cover the ``period`` before that instant. C spans the last
        1 ms calculation cycle. Biases, the walk and noise affect only the sensor
        readings (accel, ang_rate, mag, deltas, raw codes), never M or C. The noise of a
        cycle is keyed by its index, ``t`` rounded to the cycle.

        Args:
            t: Device times of the cycles [s], shape (n,).
            period: The output sample period [s]: D cycles for the deltas' noise.
            chain: What the unit's filters do; the default, a bare sensor.
            only: At least these quantities: the accel and gyro readings, DeltaAng and
                DeltaVel's quadrature, C's previous orientation, the magnetometer, Euler
                angles and the quaternion, most of the cost, are computed only when asked
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
        delay, mag_delay = chain.delays()
        seen, cycles = t - delay, _cycles(t)
        m, rate, force = self._kinematics(seen)
        stab_mag = self._ironed(m @ np.asarray(cfg.earth_field_gauss, dtype=np.float64))
        out: dict[str, np.ndarray] = {}
        if only is None or not _POINT_READINGS.isdisjoint(only):
            noise = self._chain_noise(cycles, chain.filter_width)
            if self._walk_sigma.any():
                noise = noise + self.bias_walk(seen)
            accel = force + accel_bias + noise[:, 0:3]
            ang_rate = rate + gyro_bias + noise[:, 3:6]
            out |= {"ang_rate": ang_rate, "accel": accel,
                    "raw_accel": np.clip(RAW_ZERO_CODE + accel * RAW_ACCEL_CODES_PER_G, 0,
                                         RAW_MAX_CODE),
                    "raw_ang_rate": np.clip(RAW_ZERO_CODE + ang_rate * RAW_GYRO_CODES_PER_RAD_S,
                                            0, RAW_MAX_CODE)}
        if only is None or "delta_ang" in only or "delta_vel" in only:
            out["delta_ang"], out["delta_vel"] = self._deltas(seen, m, cycles, period, chain)
        if only is None or "c" in only:
            m_prev = self._attitude(seen - CALCULATION_CYCLE_S)
            out["c"] = m @ m_prev.swapaxes(1, 2)
        if only is None or "mag" in only:
            out["mag"] = (self.magnetometer(t, chain) if mag_delay != delay else stab_mag
                          + self._chain_noise(cycles, chain.mag_filter_width, mag=True))
        if only is None or "euler" in only:
            out["euler"] = convert.m_to_euler(m)
        if only is None or "quaternion" in only:
            out["quaternion"] = convert.m_to_quaternion(m)
        return out | {
            "m": m,
            "stab_accel": -m[:, :, 2],
            "stab_mag": stab_mag,
            "temperature": np.tile(self._temperature, (t.shape[0], 1)),
        }
