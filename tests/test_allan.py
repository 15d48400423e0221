"""`gx3 allan`: a still unit's noise read off its Allan deviation, against the emulator's truth.

Hours of a still unit are written straight into an archive in virtual time from the
emulator's motion model through the unit's filter (``bridge.sim.archive_samples``), or
handed to the analysis without an archive (``tests.helpers.noise.unit_samples``), so a
test takes seconds. The densities are the sensor's: the filter averages M calculation
cycles and sends every D-th, and the read-off must see through it at every rate users
record at.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from ruamel.yaml import YAML

from bridge.analysis.allan import (
    AllanSums,
    averaging_factors,
    fit_start,
    read_off,
    white_variance,
)
from bridge.analysis.noise import (
    NOISE_KEYS,
    UnitNoise,
    UnitSamples,
    collect_samples,
    unit_noise,
    units_noise,
)
from bridge.archive.walk import read_samples_archive
from bridge.archive.writer import ArchiveWriter
from bridge.exceptions import CalibrationError, OptionError
from bridge.ros2.noise import imu_covariance, read_noise
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, SignalChain
from bridge.sim.options import SimOptions
from bridge.viz.allan import write_allan_plot
from tests.helpers.noise import unit_samples
from tests.helpers.processes import gx3

RATE = 50.0  # Hz: the random walks need hours, not a high rate
WIDTH = 20  # the filter width of the units archived at RATE: D = M
CHAIN = SignalChain(WIDTH, 17, True)
#: the emulated unit's noise in Kalibr's units; the walks cross the white noise at ~17 s
TRUTH = {"accelerometer_noise_density": 2e-3, "accelerometer_random_walk": 2e-4,
         "gyroscope_noise_density": 1e-4, "gyroscope_random_walk": 1e-5}
STILL = MotionConfig(seed=3, static=True, accelerometer_noise_density=2e-3,
                     accelerometer_random_walk=2e-4, gyroscope_noise_density=1e-4,
                     gyroscope_random_walk=1e-5)


def _seconds(start: float, end: float) -> np.ndarray:
    return np.arange(round(start * RATE), round(end * RATE)) / RATE


def _noise(path: Path, unit: str = "u1") -> UnitNoise:
    kept, take, _ = collect_samples([unit])
    read_samples_archive(path, on_blocks=take)
    return unit_noise(kept[unit])


@pytest.fixture(scope="module")
def three_hours(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("allan") / "still.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "imu-1", Motion(STILL), _seconds(0, 3 * 3600), 1 / RATE,
                        chain=CHAIN)
    return path


def test_read_off_holds_to_the_truth(three_hours: Path, tmp_path: Path) -> None:
    out, plot = tmp_path / "imu.yaml", tmp_path / "allan.png"
    done = gx3("allan", three_hours, "-u", "imu-1", "-o", out, "--plot", plot)
    assert done.returncode == 0, done.stderr
    assert "warning" not in done.stderr and "wrote" in done.stderr
    found = YAML(typ="safe").load(out.read_text())
    # Kalibr's file: its four keys, the unit's ROS 2 topic as the export names it, the rate
    assert found["rostopic"] == "/gx3/imu_1/imu" and found["update_rate"] == RATE
    extra = found["gx3_allan"]
    for key in NOISE_KEYS:
        sensor, term = key.split("_", 1)
        axes = extra[sensor]
        assert found[key] == max(axes[term])  # the worst axis
        if term == "noise_density":
            assert np.allclose(axes[term], TRUTH[key], rtol=0.05), (key, axes[term])
        else:
            sigma = np.array(axes["random_walk_sigma"])
            assert not any(axes["random_walk_upper_bound"])
            assert (sigma < 0.15 * TRUTH[key]).all(), (key, sigma)
            assert (np.abs(np.array(axes[term]) - TRUTH[key]) < 3 * sigma).all(), (
                key, axes[term], sigma)
    assert extra["samples_used"] == 3 * 3600 * RATE and extra["stretches"] == 1
    # the filter the fit modelled is the unit's, from its Info, and so is where it starts
    assert (extra["filter_width"], extra["decimation"]) == (WIDTH, 20)
    start = fit_start(WIDTH, 20)
    assert start == pytest.approx(0.4)
    assert start <= extra["fit_tau_s"][0] < start * 10**0.1 < extra["fit_tau_s"][1]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the file is what --noise of the ROS 2 outputs takes: the same numbers come out
    cov = imu_covariance(read_noise(out), RATE, WIDTH)
    assert cov.angular_velocity[0] == found["gyroscope_noise_density"] ** 2 * RATE
    assert cov.linear_acceleration[8] == found["accelerometer_noise_density"] ** 2 * RATE


def test_gaps_and_resets_cut_the_series_and_a_rollover_does_not(tmp_path: Path) -> None:
    path = tmp_path / "cut.mcap"
    motion = Motion(STILL)
    with ArchiveWriter(path) as writer:
        # the timer crosses its rollover 100 s in (its step mod 2**32 is exact: nothing
        # to cut); the cable is pulled from 600 to 630 s; the unit resets at 900 s (its
        # timer from 0 again)
        start = 2**32 - 100 * 62_500
        for first, last, timer in ((0, 600, start), (630, 900, start), (900, 1200, -900 * 62_500)):
            archive_samples(writer, "u1", motion, _seconds(first, last), 1 / RATE,
                            timer_start=timer, chain=CHAIN)
    noise = _noise(path)
    lengths = [n for _, _, n in noise.stretches]
    assert lengths == [600 * RATE, 270 * RATE, 300 * RATE]
    assert noise.used_samples == noise.samples == 1170 * RATE
    # bridged, the 30 s hole would add a step of the walk to the terms across it; cut, the
    # white noise still reads true
    assert np.allclose([a.noise_density for a in noise.gyroscope.axes], 1e-4, rtol=0.05)
    # too short for the walks: said, with how long to record
    assert any("record the unit still for 3 h" in w for w in noise.warnings)


def test_short_recording_warns_and_still_gives_the_densities(tmp_path: Path) -> None:
    path = tmp_path / "short.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 1200), 1 / RATE, chain=CHAIN)
    out = tmp_path / "imu.yaml"
    done = gx3("allan", path, "-o", out)
    assert done.returncode == 0, done.stderr
    assert "warning: unit u1: only 0.33 h of still data" in done.stderr
    assert "record the unit still for 3 h or more" in done.stderr
    found = YAML(typ="safe").load(out.read_text())
    assert found["accelerometer_noise_density"] == pytest.approx(2e-3, rel=0.05)
    assert found["gyroscope_noise_density"] == pytest.approx(1e-4, rel=0.05)
    assert found["gx3_allan"]["warnings"]
    # a random walk that is only an upper bound is said to be one, in the file and the line
    for sensor, unit in (("accelerometer", "m/s³/√Hz"), ("gyroscope", "rad/s²/√Hz")):
        axes = found["gx3_allan"][sensor]
        worst = int(np.argmax(axes["random_walk"]))
        shown = f"{found[f'{sensor}_random_walk']:.3g} {unit}"
        assert (f"K ≤ {shown}" in done.stderr) == axes["random_walk_upper_bound"][worst]
        assert f"K {shown}" in done.stderr or f"K ≤ {shown}" in done.stderr


@pytest.mark.parametrize(("rate", "width"), [(1000, 15), (500, 32), (200, 15), (250, 8)])
def test_the_densities_are_the_sensors_at_every_rate_and_width(rate: int, width: int) -> None:
    """Visual-inertial users record at 200 Hz to 1 kHz; the unit's filter averages M
    cycles and sends every D-th, which at short averaging times looks like much less
    noise. 20 minutes of a still unit (its random walks too): both densities within 5 %
    of the sensor's, read with the fit that starts at 10 (M + D) ms and models the
    filter."""
    noise = unit_noise(unit_samples(Motion(STILL), rate, width, 1200))
    assert (noise.filter_width, noise.decimation) == (width, 1000 // rate)
    assert noise.rate_hz == pytest.approx(rate)
    for sensor, truth in ((noise.accelerometer, 2e-3), (noise.gyroscope, 1e-4)):
        found = [a.noise_density for a in sensor.axes]
        assert np.allclose(found, truth, rtol=0.05), (sensor.sensor, found)
        assert all(a.fit_tau[0] >= fit_start(width, 1000 // rate) for a in sensor.axes)


def test_the_white_curve_of_the_filter_is_exact() -> None:
    """``white_variance`` against white noise averaged M at a time and decimated by D,
    made here with NumPy alone: within the estimate's own scatter at every averaging
    time with 2,000 averages or more, the filter's dip at short times and the excess of
    D > M included."""
    rng = np.random.default_rng(5)
    for width, decimation in ((15, 1), (32, 2), (15, 5), (8, 4), (15, 2), (4, 10)):
        cycles = rng.normal(0.0, np.sqrt(1000.0), 3_000_000)  # density 1: 1000 Hz a cycle
        total = np.concatenate([[0.0], np.cumsum(cycles)])
        samples = ((total[width:] - total[:-width]) / width)[::decimation]
        sums = AllanSums(averaging_factors(len(samples))[:40], 1)
        sums.add(samples[:, None])
        keep = sums.averages() >= 2000
        ratio = sums.variance()[keep, 0] / white_variance(sums.factors[keep], width, decimation)
        assert np.allclose(ratio, 1.0, atol=4 * np.sqrt(2 / sums.averages()[keep])), (
            width, decimation, ratio)


def test_the_allan_sums_match_every_start() -> None:
    """Second differences from starts m/16 apart (every start below m = 32) give the
    fully overlapping Allan variance: exactly where every start is used, and beyond
    within a fifth of the estimate's own scatter (its relative standard deviation,
    sqrt(2 / averages))."""
    rng = np.random.default_rng(2)
    y = rng.normal(0.0, 1.0, 200_000)
    sums = AllanSums(averaging_factors(len(y)), 1)
    sums.add(y[:, None])
    phase = np.concatenate([[0.0], np.cumsum(y - y.mean())])
    for j, m in enumerate(sums.factors.tolist()):
        d = phase[2 * m :] - 2 * phase[m:-m] + phase[: -2 * m]
        every = float(np.mean(d**2)) / (2 * m * m)
        scatter = np.sqrt(2 / sums.averages()[j])
        assert sums.variance()[j, 0] == pytest.approx(every, rel=1e-9 if m < 32
                                                      else 0.2 * scatter), m
        assert sums.averages()[j] == len(d) / m


def test_a_walk_bound_stays_under_every_point() -> None:
    """Without a +1/2 slope, K is the steepest +1/2 line under the whole curve drawn,
    the points left out of the fit too."""
    tau = np.geomspace(0.01, 100.0, 41)
    avar = 1e-6 / tau
    avar[:8] *= 0.2  # a filter's dip at short times, before the fit's start
    fit = read_off(tau, avar, 1e6 / tau, 1.0 / tau, fit_start(15, 1))
    assert fit.walk_bound and fit.noise_density == pytest.approx(1e-3)
    line = fit.random_walk * np.sqrt(tau / 3.0)
    assert (line <= np.sqrt(avar) * (1 + 1e-12)).all()
    assert np.isclose(line, np.sqrt(avar)).any()


def test_a_unit_that_moved_is_refused_saying_when(tmp_path: Path) -> None:
    path = tmp_path / "moved.mcap"
    moving = Motion(replace(STILL, static=False))
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 600), 1 / RATE, chain=CHAIN)
        archive_samples(writer, "u1", moving, _seconds(600, 660), 1 / RATE, chain=CHAIN)
        archive_samples(writer, "u1", Motion(STILL), _seconds(660, 1200), 1 / RATE,
                        chain=CHAIN)
    out = tmp_path / "imu.yaml"
    done = gx3("allan", path, "-o", out)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "unit u1 moved from 2025-11-13T02:23:20Z" in done.stderr
    assert "(600 s to 660 s into the span" in done.stderr and "--start/--end" in done.stderr
    assert not out.exists()
    # the still stretch before it is measured
    assert gx3("allan", path, "-o", out, "--end", "590").returncode == 0


@pytest.mark.parametrize("motion", [
    MotionConfig(seed=1),  # the demo's sway: the median of the recording is motion too
    MotionConfig(seed=2, attitude_amplitude_rad=0.0, spin_rad_s=(0.0, 0.3)),  # a turntable
    MotionConfig(seed=2, attitude_amplitude_rad=0.0, linear_accel_amplitude_g=0.3),  # a cart
])
def test_a_unit_that_moves_throughout_is_refused_even_with_a_nan(motion: MotionConfig) -> None:
    """Judged against what any still unit on earth does, not only against the recording's
    own median; a NaN sample leaves itself out of the judging, not the judging out."""
    samples = unit_samples(Motion(replace(motion, accelerometer_noise_density=2e-3,
                                          gyroscope_noise_density=1e-4)), 100, 15, 600)
    samples.accel[0][1234] = np.nan
    with pytest.raises(CalibrationError) as refused:
        unit_noise(samples)
    says = str(refused.value)
    assert says.startswith("unit u1 moved from 2025-11-13T02:13:20Z to ")
    assert "s into the span" in says and "s with motion" in says and "--start/--end" in says


def test_no_density_of_zero_is_ever_written() -> None:
    """A unit whose readings do not change (no noise at all) has no white noise to read
    off: refused, not a density of 0."""
    with pytest.raises(CalibrationError, match="no white noise shows in the accelerometer x"):
        unit_noise(unit_samples(Motion(MotionConfig(seed=3, static=True)), 100, 15, 300))


def test_the_unit_filter_is_said_when_it_is_not_known_or_leaves_cycles_out() -> None:
    """An archive without the unit's Info: the factory's width, said; D > M: each sample
    misses cycles, the densities are still the sensor's, and what Kalibr needs instead
    is said."""
    samples = unit_samples(Motion(STILL), 100, 4, 600)
    noise = unit_noise(samples)
    assert noise.filter_width == 4 and noise.width_from_info
    assert np.allclose([a.noise_density for a in noise.gyroscope.axes], 1e-4, rtol=0.05)
    assert any("its decimation (10) is larger than its filter width (4)" in w
               and "the densities times 1.58" in w for w in noise.warnings)
    samples.settings.clear()
    noise = unit_noise(samples)
    assert noise.filter_width == 15 and not noise.width_from_info
    assert any("no Info giving the unit's filter width: the factory's, 15, was assumed" in w
               for w in noise.warnings)


def test_outputs_are_the_format_their_name_says(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """-o is Kalibr's YAML: another extension is refused, not given YAML; --plot draws
    PNG, SVG or PDF as its name says, and matplotlib's own chatter (a new font cache)
    stays off the terminal."""
    path = tmp_path / "short.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 120), 1 / RATE, chain=CHAIN)
    cases: list[tuple[list[str | Path], str]] = [
        (["-o", tmp_path / "imu.json"], f"{tmp_path / 'imu.json'}: this writes a YAML "
         "file; name the file .yaml or .yml"),
        (["-o", tmp_path / "imu.yaml", "--plot", tmp_path / "a.jpg"],
         "name the file .png, .svg or .pdf")]
    for args, says in cases:
        done = gx3("allan", path, *args)
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert says in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.mcap"]
    monkeypatch.setenv("MPLCONFIGDIR", str(tmp_path / "matplotlib"))  # no font cache yet
    done = gx3("allan", path, "-o", tmp_path / "imu.yml", "--plot", tmp_path / "a.svg")
    assert done.returncode == 0, done.stderr
    assert "font" not in done.stderr.lower() and "matplotlib" not in done.stderr.lower()
    assert b"<svg" in (tmp_path / "a.svg").read_bytes()[:400]
    assert (tmp_path / "matplotlib").is_dir()  # the cache was built, quietly
    write_allan_plot(tmp_path / "a.pdf", _noise(path), "pdf")
    assert (tmp_path / "a.pdf").read_bytes()[:5] == b"%PDF-"


def test_outputs_are_never_destroyed(tmp_path: Path) -> None:
    path = tmp_path / "short.mcap"
    with ArchiveWriter(path) as writer:
        archive_samples(writer, "u1", Motion(STILL), _seconds(0, 120), 1 / RATE, chain=CHAIN)
    out = tmp_path / "imu.yaml"
    out.write_text("mine\n")
    done = gx3("allan", path, "-u", "u1", "-o", out)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--force" in done.stderr and out.read_text() == "mine\n"
    assert gx3("allan", path, "-o", out, "--force").returncode == 0
    assert "accelerometer_noise_density" in out.read_text()
    # the archive itself is an input: never an output, whatever its name
    alias = tmp_path / "alias.yaml"
    os.link(path, alias)
    done = gx3("allan", path, "-u", "u1", "-o", alias, "--force")
    assert done.returncode == 2 and "is the input" in done.stderr, done.stderr
    assert path.read_bytes()[:8] == b"\x89MCAP0\r\n"


def test_a_corrupt_archive_is_a_one_line_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 40)
    done = gx3("allan", path, "-o", tmp_path / "imu.yaml")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "nothing readable" in done.stderr and "Traceback" not in done.stderr
    other = tmp_path / "notes.txt"
    other.write_text("not an archive\n")
    done = gx3("allan", other, "-o", tmp_path / "imu.yaml")
    assert done.returncode == 2 and "not an MCAP file" in done.stderr


def test_stretches_add_up_as_one_sum() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(0, 1, (5000, 2)), rng.normal(5, 1, (3000, 2))
    factors = averaging_factors(5000)
    both = AllanSums(factors, 2)
    both.add(a)
    both.add(b)
    apart = [AllanSums(factors, 2) for _ in range(2)]
    apart[0].add(a)
    apart[1].add(b)
    assert np.allclose(both.sums, apart[0].sums + apart[1].sums)
    assert (both.counts == apart[0].counts + apart[1].counts).all()
    # white noise of unit variance: the Allan variance at m samples is 1/m
    assert np.allclose(both.variance()[:5] * factors[:5, None], 1.0, rtol=0.1)


def _white(unit: str, seed: int, seconds: float = 600.0) -> UnitSamples:
    """A still unit's samples as ``collect_samples`` keeps them: white noise about 1 g."""
    rng = np.random.default_rng(seed)
    n = round(seconds * RATE)
    step = round(62_500 / RATE)
    accel = np.array([0.0, 0.0, -1.0]) + rng.normal(0, 1e-3, (n, 3))
    return UnitSamples(unit, [10**18 + np.arange(n, dtype=np.int64) * round(1e9 / RATE)],
                       [(np.arange(n) * step).astype(np.uint32)],
                       [accel.astype(np.float32)],
                       [rng.normal(0, 1e-4, (n, 3)).astype(np.float32)])


def test_units_shared_out_among_processes_give_what_each_gives_alone() -> None:
    """gx3 allan of a fleet: a unit a process, each result (or refusal) in its place."""
    units = [_white("u1", 1), UnitSamples("none"), _white("u2", 2), _white("u3", 3)]
    alone, shared = units_noise(units, jobs=1), units_noise(units, jobs=3)
    assert [type(r) for r in shared] == [UnitNoise, CalibrationError, UnitNoise, UnitNoise]
    assert str(shared[1]) == str(alone[1]) and "unit none has no samples" in str(shared[1])
    for one, other in zip(alone, shared, strict=True):
        if isinstance(one, UnitNoise):
            assert isinstance(other, UnitNoise) and other.unit == one.unit
            assert other.stretches == one.stretches
            for sensor in ("accelerometer", "gyroscope"):
                assert np.array_equal(getattr(other, sensor).adev, getattr(one, sensor).adev,
                                      equal_nan=True)


def test_the_emulator_noise_options_are_checked() -> None:
    with pytest.raises(OptionError, match="--gyro-random-walk"):
        SimOptions(pty=True, gyro_random_walk=-1.0).setup()
    motion = SimOptions(pty=True, accel_noise_density=0.002).setup().configs[0].motion
    assert motion.accelerometer_noise_density == 0.002
