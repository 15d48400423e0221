"""The simulated ground truth must be self-consistent, or every downstream test lies."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridge.protocol.convert import (
    celsius_to_mag_temperature_code,
    euler_to_m,
    m_to_quaternion,
    quaternion_to_m,
)
from bridge.protocol.table import CALCULATION_CYCLE_S, DATA_CODES, REPLIES
from bridge.sim.motion import (
    RAW_ACCEL_CODES_PER_G,
    RAW_GYRO_CODES_PER_RAD_S,
    RAW_ZERO_CODE,
    Motion,
    MotionConfig,
    SignalChain,
    tumbling,
)

PERIOD = 0.01
T = np.arange(0.0, 20.0, PERIOD) + 3.0


@pytest.fixture(scope="module")
def motion() -> Motion:
    return Motion(MotionConfig(seed=7))


@pytest.fixture(scope="module")
def samples(motion: Motion) -> dict[str, np.ndarray]:
    return motion.sample(T, PERIOD)


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _expm_skew(theta: np.ndarray) -> np.ndarray:
    """exp([theta]x) by Rodrigues."""
    angle = float(np.linalg.norm(theta))
    k = _skew(theta / angle) if angle > 0.0 else np.zeros((3, 3))
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k


def _rotation_angle(r: np.ndarray) -> float:
    return math.acos(min(1.0, max(-1.0, (np.trace(r) - 1.0) / 2.0)))


def _simpson(f: np.ndarray, h: float) -> np.ndarray:
    w = np.ones(f.shape[0])
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    total: np.ndarray = (w @ f) * h / 3.0
    return total


def test_shapes_and_dtypes(samples: dict[str, np.ndarray]) -> None:
    n = T.shape[0]
    expected = {
        "m": (n, 3, 3),
        "euler": (n, 3),
        "quaternion": (n, 4),
        "ang_rate": (n, 3),
        "accel": (n, 3),
        "mag": (n, 3),
        "stab_accel": (n, 3),
        "stab_mag": (n, 3),
        "delta_ang": (n, 3),
        "delta_vel": (n, 3),
        "c": (n, 3, 3),
        "raw_accel": (n, 3),
        "raw_ang_rate": (n, 3),
        "temperature": (n, 4),
    }
    assert {k: v.shape for k, v in samples.items()} == expected
    for name, value in samples.items():
        assert value.dtype == (np.uint16 if name == "temperature" else np.float64), name


def test_m_is_a_rotation(samples: dict[str, np.ndarray]) -> None:
    m = samples["m"]
    np.testing.assert_allclose(
        m @ m.transpose(0, 2, 1), np.broadcast_to(np.eye(3), m.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-12)


def test_m_euler_quaternion_agree(samples: dict[str, np.ndarray]) -> None:
    m = samples["m"]
    np.testing.assert_allclose(euler_to_m(samples["euler"]), m, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_m(samples["quaternion"]), m, atol=1e-12)
    np.testing.assert_array_equal(samples["quaternion"], m_to_quaternion(m))
    assert np.all(samples["quaternion"][:, 0] >= 0.0)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_attitude_stays_clear_of_the_euler_singularity(seed: int) -> None:
    euler = Motion(MotionConfig(seed=seed)).sample(np.arange(0.0, 200.0, 0.05), 0.05)["euler"]
    assert np.abs(euler[:, 1]).max() < math.radians(60)
    assert np.abs(euler).max() <= math.pi


def test_ang_rate_is_the_body_rate_of_m(motion: Motion, samples: dict[str, np.ndarray]) -> None:
    h = 1e-5
    dm = (motion.sample(T + h, PERIOD)["m"] - motion.sample(T - h, PERIOD)["m"]) / (2 * h)
    w_cross = -dm @ samples["m"].transpose(0, 2, 1)
    np.testing.assert_allclose(w_cross + w_cross.transpose(0, 2, 1), 0.0, atol=1e-8)
    w = np.stack([w_cross[:, 2, 1], w_cross[:, 0, 2], w_cross[:, 1, 0]], axis=-1)
    np.testing.assert_allclose(w, samples["ang_rate"], atol=1e-8)
    assert np.abs(samples["ang_rate"]).max() > 0.3


def test_euler_rates_are_derivatives(motion: Motion) -> None:
    h = 1e-5
    euler, rates = motion.euler_and_rates(T)
    numeric = (motion.euler_and_rates(T + h)[0] - motion.euler_and_rates(T - h)[0]) / (2 * h)
    np.testing.assert_allclose(numeric, rates, atol=1e-8)
    assert euler.shape == rates.shape == (T.shape[0], 3)


def test_delta_ang_integrates_to_the_change_in_m(motion: Motion) -> None:
    step = 0.001
    t = 5.0 + step * np.arange(1, 1001)
    d = motion.sample(t, step)
    m = motion.sample(np.array([5.0]), step)["m"][0]
    for theta in d["delta_ang"]:
        m = _expm_skew(-theta) @ m
    assert _rotation_angle(m @ d["m"][-1].T) < 1e-3
    start = motion.sample(np.array([5.0]), step)["m"][0]
    assert _rotation_angle(start @ d["m"][-1].T) > 0.1


@pytest.mark.parametrize("period", [0.002, 0.01, 1.0])
def test_deltas_match_fine_quadrature(motion: Motion, period: float) -> None:
    ends = np.array([4.0, 9.37])
    d = motion.sample(ends, period)
    for i, end in enumerate(ends):
        fine = motion.sample(np.linspace(end - period, end, 2001), period)
        h = period / 2000
        np.testing.assert_allclose(d["delta_ang"][i], _simpson(fine["ang_rate"], h), atol=1e-9)
        np.testing.assert_allclose(d["delta_vel"][i], _simpson(fine["accel"], h), atol=1e-9)


def test_delta_vel_over_period_approximates_accel(
    motion: Motion, samples: dict[str, np.ndarray]
) -> None:
    mean_accel = samples["delta_vel"] / PERIOD
    np.testing.assert_allclose(mean_accel, samples["accel"], atol=0.02)
    # The mean over a period is the midpoint value up to period**2 / 24 times a''.
    midpoint = motion.sample(T - PERIOD / 2, PERIOD)
    np.testing.assert_allclose(mean_accel, midpoint["accel"], atol=3e-5)
    np.testing.assert_allclose(samples["delta_ang"] / PERIOD, midpoint["ang_rate"], atol=1e-3)


def test_accel_is_gravity_plus_linear_part(motion: Motion, samples: dict[str, np.ndarray]) -> None:
    m = samples["m"]
    np.testing.assert_allclose(samples["stab_accel"], m @ [0.0, 0.0, -1.0], atol=1e-15)
    linear = np.einsum("nij,nj->ni", m, motion.linear_accel_earth(T))
    np.testing.assert_allclose(samples["accel"], samples["stab_accel"] + linear, atol=1e-12)
    assert np.abs(motion.linear_accel_earth(T)).max() == pytest.approx(0.2, abs=0.05)


def test_mag_is_the_earth_field_in_the_sensor_frame(samples: dict[str, np.ndarray]) -> None:
    field = np.array([0.2, 0.0, 0.45])
    np.testing.assert_allclose(np.linalg.norm(samples["mag"], axis=1), np.linalg.norm(field))
    np.testing.assert_allclose(samples["mag"], samples["m"] @ field, atol=1e-15)
    np.testing.assert_array_equal(samples["stab_mag"], samples["mag"])


def test_c_is_the_last_calculation_cycle(motion: Motion, samples: dict[str, np.ndarray]) -> None:
    m_before = motion.sample(T - CALCULATION_CYCLE_S, PERIOD)["m"]
    np.testing.assert_allclose(samples["c"] @ m_before, samples["m"], atol=1e-12)
    small = np.stack([_expm_skew(-w * CALCULATION_CYCLE_S) for w in samples["ang_rate"][:50]])
    np.testing.assert_allclose(samples["c"][:50], small, atol=1e-5)


def test_static_unit() -> None:
    s = Motion(MotionConfig(seed=3, static=True)).sample(T, PERIOD)
    np.testing.assert_allclose(np.linalg.norm(s["accel"], axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(s["ang_rate"], 0.0)
    np.testing.assert_array_equal(s["delta_ang"], 0.0)
    np.testing.assert_allclose(s["delta_vel"], s["accel"] * PERIOD, atol=1e-15)
    np.testing.assert_array_equal(s["accel"], s["stab_accel"])
    np.testing.assert_array_equal(s["m"], np.broadcast_to(s["m"][0], s["m"].shape))
    np.testing.assert_allclose(s["c"], np.broadcast_to(np.eye(3), s["c"].shape), atol=1e-15)
    assert np.abs(s["euler"][0]).max() > 0.0


def test_level_unit_reads_minus_one_g_on_z() -> None:
    config = MotionConfig(static=True, attitude_amplitude_rad=0.0)
    s = Motion(config).sample(np.array([1.0]), PERIOD)
    np.testing.assert_allclose(s["accel"][0], [0.0, 0.0, -1.0], atol=1e-15)


def test_biases_are_added_to_the_readings() -> None:
    gyro_bias = (0.01, -0.02, 0.003)
    accel_bias = (0.005, 0.0, -0.01)
    config = MotionConfig(seed=3, static=True, gyro_bias_rad_s=gyro_bias, accel_bias_g=accel_bias)
    s = Motion(config).sample(T, PERIOD)
    unbiased = Motion(MotionConfig(seed=3, static=True)).sample(T, PERIOD)
    np.testing.assert_allclose(s["ang_rate"], np.broadcast_to(gyro_bias, s["ang_rate"].shape))
    np.testing.assert_allclose(s["delta_ang"], s["ang_rate"] * PERIOD, rtol=1e-12)
    np.testing.assert_allclose(
        s["accel"] - unbiased["accel"], np.broadcast_to(accel_bias, (T.size, 3)), atol=1e-15
    )
    expected_raw = RAW_ZERO_CODE + np.asarray(gyro_bias) * RAW_GYRO_CODES_PER_RAD_S
    np.testing.assert_allclose(s["raw_ang_rate"], np.broadcast_to(expected_raw, (T.size, 3)))
    np.testing.assert_array_equal(s["m"], unbiased["m"])
    np.testing.assert_array_equal(s["stab_accel"], unbiased["stab_accel"])


def test_raw_codes_follow_the_scaled_readings(samples: dict[str, np.ndarray]) -> None:
    np.testing.assert_allclose(
        samples["raw_accel"], RAW_ZERO_CODE + samples["accel"] * RAW_ACCEL_CODES_PER_G
    )
    np.testing.assert_allclose(
        samples["raw_ang_rate"], RAW_ZERO_CODE + samples["ang_rate"] * RAW_GYRO_CODES_PER_RAD_S
    )
    saturated = Motion(MotionConfig(static=True, accel_bias_g=(20.0, -20.0, 0.0)))
    raw = saturated.sample(np.array([0.0]), PERIOD)["raw_accel"][0]
    assert raw[0] == 131071.0
    assert raw[1] == 0.0


def test_temperature_codes() -> None:
    s = Motion(MotionConfig(temperature_c=40.0)).sample(T[:3], PERIOD)
    temperature = s["temperature"]
    assert temperature[0, 0] == round(float(celsius_to_mag_temperature_code(40.0)))
    assert np.all(np.abs(temperature[:, 1:].astype(int) - int(temperature[0, 0])) <= 60)
    np.testing.assert_array_equal(temperature, np.broadcast_to(temperature[0], temperature.shape))


def test_same_seed_same_samples_different_seed_different() -> None:
    a = Motion(MotionConfig(seed=11)).sample(T, PERIOD)
    b = Motion(MotionConfig(seed=11)).sample(T, PERIOD)
    c = Motion(MotionConfig(seed=12)).sample(T, PERIOD)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    assert np.abs(a["m"] - c["m"]).max() > 0.1


def test_samples_regenerate_one_at_a_time() -> None:
    # NumPy's SIMD and scalar trig loops may round differently, so a sample computed in
    # another batch may differ in the last float64 bit: far below the float32 wire format.
    config = MotionConfig(seed=5, noise_accel_g=0.01, noise_gyro_rad_s=0.002, noise_mag_gauss=0.003)
    batch = Motion(config).sample(T, PERIOD)
    again = Motion(config)
    for i in (0, 17, 1203, T.size - 1):
        single = again.sample(T[i : i + 1], PERIOD)
        for name in batch:
            np.testing.assert_allclose(
                single[name][0], batch[name][i], rtol=1e-13, atol=1e-15, err_msg=name
            )
            assert np.array_equal(
                single[name][0].astype(np.float32), batch[name][i].astype(np.float32)
            ), name
    window = again.sample(T[100:164], PERIOD)
    for name in batch:
        np.testing.assert_allclose(
            window[name], batch[name][100:164], rtol=1e-13, atol=1e-15, err_msg=name
        )


def test_noise_is_gaussian_with_the_configured_spread(samples: dict[str, np.ndarray]) -> None:
    config = MotionConfig(seed=7, noise_accel_g=0.01, noise_gyro_rad_s=0.002, noise_mag_gauss=0.003)
    noisy = Motion(config).sample(T, PERIOD)
    for name, sigma in (("accel", 0.01), ("ang_rate", 0.002), ("mag", 0.003)):
        error = noisy[name] - samples[name]
        np.testing.assert_allclose(error.std(axis=0), sigma, rtol=0.1)
        assert np.abs(error.mean(axis=0)).max() < 4 * sigma / math.sqrt(T.size)
    np.testing.assert_array_equal(noisy["stab_mag"], samples["stab_mag"])
    np.testing.assert_array_equal(noisy["m"], samples["m"])


def test_a_delta_sums_the_noise_of_every_cycle_of_its_period() -> None:
    """DeltaAng and DeltaVel integrate the 1 kHz samples of their period, noise and all:
    the cycles between two records count, not the record's own sample times the period."""
    config = MotionConfig(seed=7, noise_accel_g=0.01, noise_gyro_rad_s=0.002)
    chain = SignalChain(filter_width=4)
    every = np.arange(2000, 2400) * CALCULATION_CYCLE_S  # each cycle, 1 ms apart
    noise = (Motion(config).sample(every, CALCULATION_CYCLE_S, chain)["ang_rate"]
             - Motion(MotionConfig(seed=7)).sample(every, CALCULATION_CYCLE_S, chain)["ang_rate"])
    ends = every[9::10]
    deltas = [Motion(c).sample(ends, 0.01, chain)["delta_ang"] for c in (config,
                                                                     MotionConfig(seed=7))]
    summed = noise.reshape(-1, 10, 3).sum(axis=1) * CALCULATION_CYCLE_S
    np.testing.assert_allclose(deltas[0] - deltas[1], summed, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize(("width", "decimation"), [(15, 1), (32, 2), (15, 5), (8, 4), (15, 20),
                                                   (1, 10)])
def test_the_chain_averages_the_sensor_noise_cycle_by_cycle(width: int, decimation: int) -> None:
    """The moving average of M calculation cycles, every D-th sent (the manual's Filtering):
    each sample's spread is the cycle's over sqrt(M), neighbours M - D cycles apart share
    (M - D)/M of it, and a density reads back over long averages as N, or N sqrt(D/M)
    when D > M leaves cycles out."""
    density = 1e-3
    motion = Motion(MotionConfig(seed=9, static=True, gyroscope_noise_density=density))
    still = Motion(MotionConfig(seed=9, static=True))
    t = np.arange(1, 200_001) * decimation * CALCULATION_CYCLE_S
    chain = SignalChain(filter_width=width, mag_filter_width=width)
    period = decimation * CALCULATION_CYCLE_S
    y = (motion.sample(t, period, chain, only=["ang_rate"])["ang_rate"]
         - still.sample(t, period, chain, only=["ang_rate"])["ang_rate"])
    cycle = density * math.sqrt(1000.0)
    np.testing.assert_allclose(y.std(axis=0), cycle / math.sqrt(width), rtol=0.02)
    shared = np.mean([np.corrcoef(y[1:, i], y[:-1, i])[0, 1] for i in range(3)])
    assert shared == pytest.approx(max(width - decimation, 0) / width, abs=0.01)
    block = 2000 // decimation  # means of 2 s
    means = y[: len(y) // block * block].reshape(-1, block, 3).mean(axis=1)
    read = means.std() * math.sqrt(block * period)
    assert read == pytest.approx(density * math.sqrt(max(decimation / width, 1.0)), rel=0.05)


def test_coning_makes_delta_ang_the_rotation_vector_of_the_turn() -> None:
    """With coning and sculling (0xDB flag bit 1), a tumbling unit's DeltaAngles chain up
    to its attitude exactly, and its DeltaVelocities, each taken into the earth frame at
    its period's start, sum to the integral of the earth-frame specific force; without,
    they are the plain integrals, which miss the coning and sculling terms."""
    motion = Motion(tumbling(MotionConfig(seed=4)))
    period, n = 0.02, 250
    ends = 5.0 + period * np.arange(1, n + 1)
    start_m = motion.sample(np.array([5.0]), period)["m"][0]
    errors = {}
    for coning in (True, False):
        chain = SignalChain(coning_sculling=coning)
        d = motion.sample(ends, period, chain)
        m, velocity = start_m, np.zeros(3)
        for theta, dv in zip(d["delta_ang"], d["delta_vel"], strict=True):
            velocity += m.T @ dv
            m = _expm_skew(-theta) @ m
        fine = np.linspace(5.0, ends[-1], 200_001)
        force = np.einsum("nji,nj->ni", motion.sample(fine, period)["m"],
                          motion.sample(fine, period)["accel"])
        errors[coning] = (float(np.abs(m - d["m"][-1]).max()),
                          float(np.abs(velocity - _simpson(force, fine[1] - fine[0])).max()))
    assert errors[True][0] < 1e-11 and errors[True][1] < 1e-9
    assert errors[False][0] > 1e-4 and errors[False][1] > 1e-4


def test_rejects_bad_arguments(motion: Motion) -> None:
    with pytest.raises(ValueError, match="period"):
        motion.sample(T, 0.0)
    with pytest.raises(ValueError, match="one-dimensional"):
        motion.sample(T.reshape(-1, 2), PERIOD)
    assert motion.sample(2.5, PERIOD)["m"].shape == (1, 3, 3)


SOFT = (1.1, 0.05, 0.0, 0.05, 0.9, -0.02, 0.0, -0.02, 1.0)
HARD = (0.12, -0.3, 0.05)


def test_the_magnetometer_reads_the_field_through_soft_and_hard_iron() -> None:
    clean = Motion(MotionConfig(seed=3)).sample(T, PERIOD)
    ironed = Motion(MotionConfig(seed=3, hard_iron_gauss=HARD, soft_iron=SOFT))
    s = ironed.sample(T, PERIOD)
    expected = clean["mag"] @ np.reshape(SOFT, (3, 3)).T + HARD
    np.testing.assert_allclose(s["mag"], expected, atol=1e-12)
    np.testing.assert_array_equal(s["stab_mag"], s["mag"])
    np.testing.assert_array_equal(ironed.magnetometer(T), s["mag"])
    np.testing.assert_array_equal(s["m"], clean["m"])


def test_a_tumbling_unit_points_the_field_every_way() -> None:
    """Body-frame field directions of a tumbling unit reach every octant, a swaying one not."""
    t = np.arange(0.0, 90.0, 0.05)

    def octants(config: MotionConfig) -> int:
        mag = Motion(config).magnetometer(t)
        return len({tuple(row) for row in (mag > 0).tolist()})

    assert octants(tumbling(MotionConfig(seed=4))) == 8
    assert octants(MotionConfig(seed=4)) < 8
    euler = Motion(tumbling(MotionConfig(seed=4))).euler_and_rates(t)[0]
    assert np.abs(euler[:, 1]).max() <= math.radians(55.0) + 1e-9
    assert np.ptp(euler[:, 0]) > 2 * np.pi and np.ptp(euler[:, 2]) > 2 * np.pi


def test_a_spin_turns_roll_and_yaw_steadily() -> None:
    t = np.arange(0.0, 10.0, 0.5)
    euler = Motion(MotionConfig(seed=4, attitude_amplitude_rad=0.0,
                                spin_rad_s=(0.3, -0.5))).euler_and_rates(t)[0]
    np.testing.assert_allclose(euler[:, 0] - euler[0, 0], 0.3 * t, atol=1e-12)
    np.testing.assert_array_equal(euler[:, 1], 0.0)
    np.testing.assert_allclose(euler[:, 2] - euler[0, 2], -0.5 * t, atol=1e-12)


def test_a_record_types_quantities_alone_are_the_same_values() -> None:
    """The emulator computes only what a record holds: the same bits as computing all."""
    motion = Motion(MotionConfig(seed=5))
    full = motion.sample(T, PERIOD)
    for code in DATA_CODES:
        names = [f.name for f in REPLIES[code].fields if f.name != "timer"]
        alone = motion.sample(T, PERIOD, only=names)
        for name in names:
            assert np.array_equal(alone[name], full[name]), (hex(code), name)
