"""Iron calibration against the emulator's truth: what it finds, and when it refuses."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.analysis.magcal import fit
from bridge.exceptions import CalibrationError
from bridge.protocol import convert
from bridge.sim.motion import Motion, MotionConfig, tumbling

SOFT = (1.1, 0.05, 0.0, 0.05, 0.9, -0.02, 0.0, -0.02, 1.0)
HARD = (0.12, -0.3, 0.05)
EARTH = np.array([0.2, 0.0, 0.45])
FIELD = float(np.linalg.norm(EARTH))
T = np.arange(0.0, 90.0, 0.01)


def ironed(config: MotionConfig) -> Motion:
    return Motion(MotionConfig(**{**vars(config), "hard_iron_gauss": HARD, "soft_iron": SOFT,
                                  "noise_mag_gauss": 0.002}))


def test_a_tumbling_unit_gives_the_true_iron() -> None:
    motion = ironed(tumbling(MotionConfig(seed=4)))
    cal = fit(motion.magnetometer(T))
    assert np.linalg.norm(cal.hard_iron - HARD) < 0.01 * FIELD
    np.testing.assert_array_equal(cal.soft_iron, cal.soft_iron.T)
    truth = convert.euler_to_m(motion.euler_and_rates(T)[0]) @ EARTH
    corrected = cal.correct(truth @ np.reshape(SOFT, (3, 3)).T + HARD)
    size = np.linalg.norm(corrected, axis=1)
    assert np.abs(size / size.mean() - 1).max() < 0.005
    assert size.mean() == pytest.approx(cal.field_gauss, rel=0.01)
    assert cal.coverage == 1.0 and not cal.warnings
    assert cal.residual_before > 0.1 > 0.01 > cal.residual_after
    assert cal.readings == len(T)


@pytest.mark.parametrize(("column", "axis", "others"), [(0, "x", "y and z"),
                                                        (2, "z", "x and y")])
def test_a_turn_about_one_axis_is_refused_naming_the_missing_tilt(
        column: int, axis: str, others: str) -> None:
    euler = np.zeros((len(T), 3))
    euler[:, column] = 0.5 * T
    raw = convert.euler_to_m(euler) @ EARTH @ np.reshape(SOFT, (3, 3)).T + HARD
    raw += np.random.default_rng(1).normal(0.0, 0.002, raw.shape)
    with pytest.raises(CalibrationError, match="span a plane") as caught:
        fit(raw)
    assert f"about one axis only (its {axis} axis)" in str(caught.value)
    assert f"tilt it: turn it also about its {others} axes" in str(caught.value)


def test_a_still_unit_is_refused() -> None:
    raw = ironed(MotionConfig(seed=4, static=True)).magnetometer(T)
    with pytest.raises(CalibrationError, match="stood still"):
        fit(raw)


@pytest.mark.parametrize("amplitude", [0.25, 0.3, 0.4, 0.6, 0.8])
@pytest.mark.parametrize("seed", [4, 5, 6])
def test_a_swaying_unit_is_refused_naming_the_unseen_axes(seed: int, amplitude: float) -> None:
    """Never upside down, the field only seen from one side: fits there are off by up to
    96 % of the field, some of them stretched over most of the sphere."""
    raw = ironed(MotionConfig(seed=seed, attitude_amplitude_rad=amplitude)).magnetometer(T)
    with pytest.raises(CalibrationError, match="from one side only") as caught:
        fit(raw)
    assert "never lay along its" in str(caught.value) or "mostly along its" in str(
        caught.value)


def test_a_unit_that_stood_still_half_the_time_gets_a_fit_with_a_warning() -> None:
    tumbler = ironed(tumbling(MotionConfig(seed=4)))
    still = ironed(MotionConfig(seed=4, static=True))
    cal = fit(np.concatenate([tumbler.magnetometer(T), still.magnetometer(T)]))
    assert np.linalg.norm(cal.hard_iron - HARD) < 0.01 * FIELD
    assert len(cal.warnings) == 1 and "unevenly" in cal.warnings[0]


def test_too_few_readings_are_refused() -> None:
    raw = ironed(tumbling(MotionConfig(seed=4))).magnetometer(T[:20])
    raw[3] = np.nan
    with pytest.raises(CalibrationError, match="19 magnetometer readings"):
        fit(raw)


def test_readings_on_no_ellipsoid_are_refused() -> None:
    """Points on a hyperboloid x² + y² - z² = 0.04: a quadric, but no iron makes it."""
    angle, z = np.meshgrid(np.linspace(0, 2 * np.pi, 40), np.linspace(-0.5, 0.5, 20))
    radius = np.sqrt(0.04 + z**2)
    raw = np.stack([radius * np.cos(angle), radius * np.sin(angle), z], -1).reshape(-1, 3)
    with pytest.raises(CalibrationError, match="do not lie on an ellipsoid"):
        fit(raw)
