"""How units on one body are aligned, across the settings users run: output rates 25 Hz to
1 kHz (two units at different rates too), rates from angular rate or DeltaAngle records,
time stamps with jitter, noise and biases; the 1-sigma it states; a lever arm that the
motion does not show; and the motion that cannot give a rotation, refused saying what to
record (through `gx3 align`: one line, exit 2, nothing written)."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bridge.analysis.align import UnitMotion, align, fit_mount, unit_motion
from bridge.analysis.mounts import read_mounts
from bridge.archive.writer import ArchiveWriter
from bridge.exceptions import AlignmentError
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.protocol.table import DEFAULT_FILTER_WIDTH, TICKS_PER_SECOND
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, Mounting, SignalChain, handheld
from tests.helpers.processes import gx3

T0 = 1_763_000_000_000_000_000
FLIPPED = Mounting.turned((180.0, 0.0, 90.0), (0.3, -0.1, 0.2), 3)
REFERENCE = Mounting(3)
#: Every unit's filter as it leaves the factory: the noise its samples carry at each rate.
CHAIN = SignalChain(DEFAULT_FILTER_WIDTH)


def _motion(mounting: Mounting, seed: int = 1, noise: float = 0.0005,
            changes: dict[str, object] | None = None) -> Motion:
    config = handheld(MotionConfig(seed=seed, accelerometer_noise_density=noise,
                                   gyroscope_noise_density=noise / 4,
                                   gyro_bias_rad_s=(0.003, -0.002, 0.001),
                                   accel_bias_g=(0.002, 0.001, -0.003)), mounting)
    return Motion(replace(config, **changes or {}))  # type: ignore[arg-type]


def _sampled(name: str, motion: Motion, rate_hz: float, seconds: float = 60.0,
             late_s: float = 0.0, jitter_s: float = 0.0) -> UnitMotion:
    """A unit's rates and forces at its own rate, stamped ``late_s`` late, with jitter."""
    rng = np.random.default_rng(len(name))
    t = np.arange(0.0, seconds, 1.0 / rate_hz) + rng.uniform(0, 1.0 / rate_hz)
    s = motion.sample(t, 1.0 / rate_hz, CHAIN, only=("accel", "ang_rate"))
    stamps = t + late_s + rng.normal(0.0, jitter_s, len(t)) if jitter_s else t + late_s
    return UnitMotion(name, T0 + np.round(stamps * 1e9).astype(np.int64), s["ang_rate"],
                      s["accel"] * STANDARD_GRAVITY)


def _angle_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


@pytest.mark.parametrize(("ref_hz", "unit_hz"), [(25, 25), (100, 1000), (1000, 25),
                                                 (500, 500)])
def test_every_rate_gives_the_mounting_and_the_shift(ref_hz: float, unit_hz: float) -> None:
    """Time stamps 50 us apart at random (a USB frame's jitter) and 2.5 ms late."""
    ref = _sampled("ref", _motion(REFERENCE), ref_hz, jitter_s=5e-5)
    unit = _sampled("unit", _motion(FLIPPED, seed=2), unit_hz, late_s=0.0025, jitter_s=5e-5)
    mount = fit_mount(ref, unit)
    assert _angle_deg(mount.rotation @ FLIPPED.matrix.T) < 0.1
    assert mount.time_shift_s == pytest.approx(-0.0025, abs=1e-4)
    assert mount.lever_arm_m is not None
    np.testing.assert_allclose(mount.lever_arm_m, FLIPPED.lever_arm_m, atol=0.02)


def test_the_stated_uncertainty_covers_the_error() -> None:
    """With exact time stamps, what is left is the sensors' noise, which the 1-sigma
    states: every error within 4 of it, and not all within 0.3 (a 1-sigma blown up)."""
    ref = _sampled("ref", _motion(REFERENCE, noise=0.004), 100)
    unit = _sampled("unit", _motion(FLIPPED, seed=3, noise=0.004), 100, late_s=0.001)
    mount = fit_mount(ref, unit)
    fit = mount.fit
    assert fit is not None and fit.lever_arm_sigma_m is not None
    assert mount.lever_arm_m is not None
    turn = mount.rotation.T @ FLIPPED.matrix  # the small turn left, in the reference's axes
    theta = np.degrees([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0],
                        turn[1, 0] - turn[0, 1]]) / 2
    z = np.concatenate([theta / fit.rotation_sigma_deg,
                        [(mount.time_shift_s + 0.001) / fit.time_shift_sigma_s],
                        (mount.lever_arm_m - FLIPPED.lever_arm_m) / fit.lever_arm_sigma_m])
    assert np.abs(z).max() < 4
    assert np.abs(z).max() > 0.3


def test_rates_from_delta_records_are_timed_at_their_periods_middle() -> None:
    """A DeltaAngle/DeltaVelocity unit (0xC3) against an angular-rate one (0xC2): the
    integrals over each period, over the period, stand for the rate at its middle."""
    period = 0.01
    t = np.arange(0.0, 60.0, period) + 0.0031
    deltas = _motion(FLIPPED, seed=2).sample(t, period, CHAIN, only=("delta_ang", "delta_vel"))
    table = {"unit": np.array(["unit"] * len(t)), "ticks": np.round(
        t * TICKS_PER_SECOND).astype(np.int64), "time_ns": T0 + np.round(
        (t - period / 2) * 1e9).astype(np.int64)}
    for name in ("delta_ang", "delta_vel"):
        for i, axis in enumerate("xyz"):
            table[f"{name}_{axis}"] = deltas[name][:, i].astype(np.float32)
    unit = unit_motion(table, "unit")
    mount = fit_mount(_sampled("ref", _motion(REFERENCE), 100), unit)
    assert _angle_deg(mount.rotation @ FLIPPED.matrix.T) < 0.1
    assert abs(mount.time_shift_s) < 1e-4
    assert mount.lever_arm_m is not None
    np.testing.assert_allclose(mount.lever_arm_m, FLIPPED.lever_arm_m, atol=0.02)


def test_a_lever_arm_the_motion_does_not_show_is_left_out_saying_why() -> None:
    """Slow sways (rates of a few tenths of rad/s, changing over seconds) show the
    rotation, but move the forces too little to tell where the unit sits."""
    slow: dict[str, object] = {"band_hz": (0.03, 0.08), "attitude_amplitude_rad": 0.5,
            "linear_accel_amplitude_g": 0.02}
    ref = _sampled("ref", _motion(REFERENCE, changes=slow), 100)
    unit = _sampled("unit", _motion(FLIPPED, seed=2, changes=slow), 100)
    mount = fit_mount(ref, unit)
    assert _angle_deg(mount.rotation @ FLIPPED.matrix.T) < 0.1
    assert mount.lever_arm_m is None and mount.fit is not None
    assert mount.fit.lever_arm_note.startswith("not observable: along")
    assert "turn the body back and forth more briskly" in mount.fit.lever_arm_note


@pytest.mark.parametrize(("changes", "message"), [
    ({"static": True}, "ref hardly turned from"),
    ({"attitude_amplitude_rad": 0.0, "spin_rad_s": (0.0, 0.8)},
     "ref turned about one axis only (its z axis)"),
])
def test_motion_that_shows_no_rotation_is_refused(changes: dict[str, object],
                                                 message: str) -> None:
    ref = _sampled("ref", _motion(REFERENCE, changes=changes), 100)
    unit = _sampled("unit", _motion(FLIPPED, seed=2, changes=changes), 100)
    with pytest.raises(AlignmentError, match=re.escape(message)):
        align([ref, unit])


def test_units_that_do_not_share_a_body_are_refused() -> None:
    ref = _sampled("ref", _motion(REFERENCE), 100)
    other = _sampled("other", _motion(Mounting(9), seed=2), 100)
    with pytest.raises(AlignmentError, match="other does not turn with ref"):
        align([ref, other])


def _archive(path: Path, units: dict[str, tuple[Motion, float, float]]) -> Path:
    """Units archived as their bridges publish them: motion, first second, seconds."""
    with ArchiveWriter(path) as writer:
        for unit, (motion, start, seconds) in units.items():
            archive_samples(writer, unit, motion, np.arange(start, start + seconds, 0.01),
                            0.01)
    return path


@pytest.fixture(scope="module")
def refusals(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A reference turned by hand with one unit beside it, a still pair and a pair turned
    about one axis, and a unit recorded after the reference had stopped."""
    still: dict[str, object] = {"static": True}
    spun: dict[str, object] = {"attitude_amplitude_rad": 0.0, "spin_rad_s": (0.0, 0.8)}
    return _archive(tmp_path_factory.mktemp("refusals") / "refusals.mcap", {
        "ref": (_motion(REFERENCE), 0.0, 30.0), "unit": (_motion(FLIPPED, 2), 0.0, 30.0),
        "later": (_motion(FLIPPED, 2), 40.0, 20.0),
        "still1": (_motion(Mounting(4), 3, changes=still), 0.0, 30.0),
        "still2": (_motion(Mounting(4), 4, changes=still), 0.0, 30.0),
        "spun1": (_motion(Mounting(5), 5, changes=spun), 0.0, 30.0),
        "spun2": (_motion(Mounting(5), 6, changes=spun), 0.0, 30.0)})


@pytest.mark.parametrize(("units", "output", "message"), [
    (["ref"], "m.yaml", "give two units or more: the reference first"),
    (["ref", "nobody"], "m.yaml", "has no unit nobody (units: later, ref, spun1"),
    (["ref", "later"], "m.yaml", "ref and later: they have no samples at the same time"),
    (["still1", "still2"], "m.yaml", "the body stood still; record it turned by hand"),
    (["spun1", "spun2"], "m.yaml", "turned about one axis only (its z axis)"),
    (["ref", "unit"], "m.json", "this writes a YAML file; name the file .yaml or .yml"),
])
def test_refusals_are_one_line_and_write_nothing(refusals: Path, tmp_path: Path,
                                                 units: list[str], output: str,
                                                 message: str) -> None:
    done = gx3("align", refusals, *(a for u in units for a in ("-u", u)), "-o",
               tmp_path / output)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    assert not list(tmp_path.iterdir())


def test_the_units_recorded_together_are_aligned(refusals: Path, tmp_path: Path) -> None:
    """The same archive, the units that share a body: written, as found."""
    out = tmp_path / "m.yaml"
    done = gx3("align", refusals, "-u", "ref", "-u", "unit", "-o", out)
    assert done.returncode == 0, done.stderr
    mount = read_mounts(out).units["unit"]
    assert _angle_deg(mount.rotation @ FLIPPED.matrix.T) < 0.1
    assert abs(mount.time_shift_s) < 1e-4
