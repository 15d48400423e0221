"""A still unit's IMU noise from an archive: what Kalibr, VINS and OpenVINS ask for.

The archive is read once, chunk by chunk (``read_archive``'s ``on_blocks``): of each
unit asked for, only its accelerations and angular rates, the timer and the sample
times are kept, as float32 and integer columns (36 bytes a sample, never a Python
object each), and the file's chunks are dropped as they are decoded. Each unit's
samples are then cut into contiguous stretches wherever its timer does not step by one
sample period (a gap, a reset, a rollover: never bridged), checked for motion, and
handed to ``bridge.analysis.allan``; several units share the cores (``units_noise``).

A Kalibr ``imu.yaml`` (``kalibr_yaml``) holds the worst axis of each sensor, in
Kalibr's units (m/s², rad/s; densities per √Hz, random walks per s per √Hz), with the
unit's ROS 2 topic as ``gx3 export`` names it and its rate. What else was found (each
axis, bias instability, the span and stretches used) goes under one extra key,
``gx3_allan``, which Kalibr ignores.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bridge._text import counted, number, utc_text
from bridge._workers import Workers, share_out
from bridge.analysis.allan import (
    MIN_FACTOR,
    AllanSums,
    NoiseFit,
    averaging_factors,
    read_off,
)
from bridge.archive.reader import ArchiveReader
from bridge.exceptions import CalibrationError
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.protocol.table import TICKS_PER_SECOND

__all__ = ["NOISE_KEYS", "SensorNoise", "UnitNoise", "UnitSamples", "collect_samples",
           "kalibr_yaml", "stretch_text", "unit_noise", "units_noise"]

#: What Kalibr reads, in its order; the rest of the file is ours.
NOISE_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk",
              "gyroscope_noise_density", "gyroscope_random_walk")
#: Still data under which the random walks are uncertain (Kalibr's wiki: hours).
MIN_WALK_S = 3 * 3600.0
#: A still unit's one-second means stay this close to their median, unless its own
#: noise says more: |specific force| (m/s²) and angular rate (rad/s).
MOVED_ACCEL = 0.1
MOVED_RATE = 0.01
#: ... and within this many times the median of those departures.
MOVED_FACTOR = 10.0
#: A second's spread of samples this many times the median second's is motion too
#: (a knock, handling), in seconds of at least _MIN_SPREAD_SAMPLES samples.
MOVED_SPREAD = 5.0
_MIN_SPREAD_SAMPLES = 5
_WRAP = 1 << 32
_AXES = "xyz"


@dataclass
class UnitSamples:
    """A unit's samples that have acceleration and angular rate, in archive order.

    Attributes:
        unit: The unit's name.
        time_ns: Each sample's instant, host ns.
        timer: The unit's timer at each (62.5 kHz, wraps at 2**32).
        accel: Specific force, g, (n, 3) float32.
        ang_rate: Angular rate, rad/s, (n, 3) float32.
        other_codes: Record types of the unit that lack either, and were left out.
    """

    unit: str
    time_ns: list[np.ndarray] = field(default_factory=list)
    timer: list[np.ndarray] = field(default_factory=list)
    accel: list[np.ndarray] = field(default_factory=list)
    ang_rate: list[np.ndarray] = field(default_factory=list)
    other_codes: set[int] = field(default_factory=set)

    def __len__(self) -> int:
        return sum(len(t) for t in self.time_ns)


def collect_samples(units: Sequence[str] | None) -> tuple[
        dict[str, UnitSamples], Callable[[ArchiveReader], None], list[int]]:
    """A consumer for ``read_archive(on_blocks=...)`` that keeps what the noise needs.

    Args:
        units: The units to keep; None: every unit.

    Returns:
        The units' samples as they fill, the consumer, and a one-element list holding
        the earliest sample time of any unit (for --start/--end in seconds), or empty.
    """
    kept: dict[str, UnitSamples] = {}
    first: list[int] = []

    def take(archive: ArchiveReader) -> None:
        earliest = archive.first_sample_ns()
        if earliest is not None:
            first[:] = [min([*first, earliest])]
        for block in archive.samples(units):
            unit = kept.setdefault(block.unit, UnitSamples(block.unit))
            cols = block.columns
            if "accel" not in cols or "ang_rate" not in cols:
                unit.other_codes.add(block.code)
                continue
            unit.time_ns.append(cols["time_ns"].astype(np.int64))
            unit.timer.append(cols["timer"].astype(np.uint32))
            unit.accel.append(cols["accel"].astype(np.float32))
            unit.ang_rate.append(cols["ang_rate"].astype(np.float32))

    return kept, take, first


@dataclass(frozen=True)
class SensorNoise:
    """One sensor's Allan deviation per axis and the noise read off it.

    Attributes:
        sensor: ``accelerometer`` or ``gyroscope``.
        unit: Its rate's unit: ``m/s^2`` or ``rad/s``.
        adev: Allan deviation, (3, averaging times), NaN where not computed.
        axes: What each axis's curve gives.
    """

    sensor: str
    unit: str
    adev: np.ndarray
    axes: tuple[NoiseFit, NoiseFit, NoiseFit]

    @property
    def noise_density(self) -> float:
        """The worst axis's white noise density: the one number Kalibr takes."""
        return max(a.noise_density for a in self.axes)

    @property
    def random_walk(self) -> float:
        """The worst axis's bias random walk."""
        return max(a.random_walk for a in self.axes)


@dataclass(frozen=True)
class UnitNoise:
    """A unit's noise, and what it was read from.

    Attributes:
        unit: The unit's name.
        rate_hz: Its sample rate (from its timer).
        tau: Averaging times, s.
        accelerometer: The accelerometer's curves and read-off (m/s²).
        gyroscope: The gyroscope's (rad/s).
        stretches: (first ns, last ns, samples) of each contiguous stretch used.
        samples: Samples in the span asked for.
        warnings: What the user should know (short data, samples left out).
    """

    unit: str
    rate_hz: float
    tau: np.ndarray
    accelerometer: SensorNoise
    gyroscope: SensorNoise
    stretches: tuple[tuple[int, int, int], ...]
    samples: int
    warnings: tuple[str, ...]

    @property
    def used_samples(self) -> int:
        """Samples in the stretches used."""
        return sum(s[2] for s in self.stretches)

    @property
    def used_seconds(self) -> float:
        """Seconds of still data in the stretches used."""
        return self.used_samples / self.rate_hz



def _sample_step(timer: np.ndarray) -> tuple[np.ndarray, float]:
    """Each sample-to-sample timer step (mod 2**32) and the unit's step, in ticks.

    The step is the median; a decimation of an odd number of ms steps by 62.5 ticks
    times it, alternately rounded down and up, so the steps within a tick of the median
    are averaged to give the period.
    """
    steps: np.ndarray = np.mod(np.diff(timer.astype(np.int64)), _WRAP)
    median = float(np.median(steps)) if len(steps) else 0.0
    regular = np.abs(steps - median) <= 1.0
    return steps, float(steps[regular].mean()) if regular.any() else median


def _stretch_bounds(timer: np.ndarray, steps: np.ndarray, step: float) -> np.ndarray:
    """Where each contiguous stretch starts, and the end.

    A stretch is cut wherever the timer does not move on by one period (a gap, a
    repeat) or goes back (a reset, a rollover).
    """
    t = timer.astype(np.int64)
    cut = (np.abs(steps - step) > 1.0) | (t[1:] < t[:-1])
    return np.concatenate([[0], np.flatnonzero(cut) + 1, [len(timer)]])


def _moved(time_ns: np.ndarray, force: np.ndarray, rate: np.ndarray, unit: str) -> None:
    """Refuse samples in which the unit moved, naming when.

    Per second of samples: the mean |specific force| and mean angular rate against
    their medians over the recording, and the spread within the second against the
    median second's; beyond what a still unit's own noise and drift give (and a floor),
    the unit moved.
    """
    second = (time_ns - time_ns[0]) // 1_000_000_000
    _, index, counts = np.unique(second, return_inverse=True, return_counts=True)
    magnitude = np.linalg.norm(force, axis=1)

    def mean(values: np.ndarray) -> np.ndarray:
        out: np.ndarray = np.bincount(index, values, len(counts)) / counts
        return out

    f_mean = mean(magnitude)
    r_mean = np.column_stack([mean(rate[:, i]) for i in range(3)])
    f_off = np.abs(f_mean - np.median(f_mean))
    r_off = np.linalg.norm(r_mean - np.median(r_mean, axis=0), axis=1)
    moved = ((f_off > max(MOVED_ACCEL, MOVED_FACTOR * float(np.median(f_off))))
             | (r_off > max(MOVED_RATE, MOVED_FACTOR * float(np.median(r_off)))))
    full = counts >= _MIN_SPREAD_SAMPLES
    if full.any():
        f_spread = np.sqrt(mean(magnitude**2) - f_mean**2).clip(0)
        r_spread = np.sqrt(sum(mean(rate[:, i] ** 2) - r_mean[:, i] ** 2
                               for i in range(3)).clip(0))
        for spread in (f_spread, r_spread):
            typical = float(np.median(spread[full]))
            moved |= full & (spread > MOVED_SPREAD * typical) & (typical > 0)
    if not moved.any():
        return
    seconds = np.flatnonzero(moved)
    start = np.flatnonzero(index == seconds[0])[0]
    end = np.flatnonzero(index == seconds[-1])[-1]
    first_s = (time_ns[start] - time_ns[0]) / 1e9
    last_s = (time_ns[end] - time_ns[0]) / 1e9
    raise CalibrationError(
        f"unit {unit} moved from {utc_text(int(time_ns[start]))} to "
        f"{utc_text(int(time_ns[end]))} "
        f"({first_s:.0f} s to {last_s:.0f} s into the span, {len(seconds)} s with motion: "
        f"|specific force| up to {float(f_off.max()):.3g} m/s² off its still value, rate "
        f"{float(r_off.max()):.3g} rad/s); the noise needs a unit that stays still: "
        "record again without touching it, or give --start/--end around a still stretch")


def unit_noise(samples: UnitSamples, start_ns: int | None = None,
               end_ns: int | None = None) -> UnitNoise:
    """A unit's Allan deviation and its noise, from its archived samples.

    Args:
        samples: The unit's samples (``collect_samples``).
        start_ns: Only samples at or after this (host ns).
        end_ns: Only samples before this.

    Returns:
        Its noise, and what it was read from.

    Raises:
        CalibrationError: No samples with accel and rate in the span, too few to average,
            or the unit moved.
    """
    name = samples.unit
    if not len(samples):
        kinds = ", ".join(f"0x{c:02X}" for c in sorted(samples.other_codes)) or "none"
        raise CalibrationError(
            f"unit {name} has no samples with both acceleration and angular rate (record "
            f"types it has: {kinds}); stream a type with both, such as 0xC2, 0xC8 or 0xCC")
    time_ns = np.concatenate(samples.time_ns)
    order = np.argsort(time_ns, kind="stable")
    keep = np.ones(len(order), bool)
    if start_ns is not None:
        keep &= time_ns[order] >= start_ns
    if end_ns is not None:
        keep &= time_ns[order] < end_ns
    order = order[keep]
    if len(order) < 2 * MIN_FACTOR:
        raise CalibrationError(f"unit {name}: {len(order)} samples from --start to --end; "
                               "the noise needs minutes of a still unit, hours for the "
                               "random walks")
    time_ns = time_ns[order]
    timer = np.concatenate(samples.timer)[order]
    rates = np.empty((len(order), 6))  # accel (m/s²) then gyro (rad/s): one array for all
    rates[:, :3] = np.concatenate(samples.accel)[order]
    rates[:, :3] *= STANDARD_GRAVITY
    rates[:, 3:] = np.concatenate(samples.ang_rate)[order]
    _moved(time_ns, rates[:, :3], rates[:, 3:], name)
    steps, step = _sample_step(timer)
    period = step / TICKS_PER_SECOND
    bounds = _stretch_bounds(timer, steps, step)
    spans = [(a, b) for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)
             if b - a >= 2 * MIN_FACTOR]
    if not spans:
        raise CalibrationError(f"unit {name}: no stretch of {2 * MIN_FACTOR} samples without "
                               "a gap; record the still unit for minutes without interruption")
    sums = AllanSums(averaging_factors(max(b - a for a, b in spans)), 6)
    finite = np.all(np.isfinite(rates), axis=1)
    used = []
    for a, b in spans:
        # a NaN (a unit sending none) cuts a stretch like a gap
        inner = np.flatnonzero(~finite[a:b]) + a
        for lo, hi in zip([a, *(inner + 1).tolist()], [*inner.tolist(), b], strict=True):
            if hi - lo >= 2 * MIN_FACTOR:
                sums.add(rates[lo:hi])
                used.append((int(time_ns[lo]), int(time_ns[hi - 1]), hi - lo))
    tau = sums.factors * period
    adev = np.sqrt(sums.variance()).T
    avar, averages = sums.variance(), sums.averages()
    fits = [read_off(tau, avar[:, i], averages, period) for i in range(6)]
    warnings = []
    seconds = sums.samples * period
    if seconds < MIN_WALK_S:
        warnings.append(
            f"only {seconds / 3600:.2g} h of still data: the noise densities hold, but the "
            "random walks need hours (" + ", ".join(
                f"{'upper bounds' if any(f.walk_bound for f in part) else 'uncertain'} "
                f"for the {sensor}" for sensor, part in (("accelerometer", fits[:3]),
                                                         ("gyroscope", fits[3:])))
            + f"); record the unit still for {MIN_WALK_S / 3600:.0f} h or more (8 h for "
            "a tight estimate)")
    elif any(f.walk_bound for f in fits):
        warnings.append("no random walk shows in "
                        + ", ".join(f"{('accelerometer', 'gyroscope')[i // 3]} "
                                    f"{_AXES[i % 3]}" for i, f in enumerate(fits)
                                    if f.walk_bound)
                        + "; its random walk is an upper bound: record longer to see it")
    left_out = len(order) - sums.samples
    if left_out:
        warnings.append(f"{left_out} of {len(order)} samples left out: stretches of "
                        f"fewer than {2 * MIN_FACTOR} samples between gaps, or NaN values")
    return UnitNoise(
        unit=name, rate_hz=1.0 / period, tau=tau,
        accelerometer=SensorNoise("accelerometer", "m/s^2", adev[0:3],
                                  (fits[0], fits[1], fits[2])),
        gyroscope=SensorNoise("gyroscope", "rad/s", adev[3:6], (fits[3], fits[4], fits[5])),
        stretches=tuple(used), samples=len(order), warnings=tuple(warnings))


def _noise_or_refusal(samples: UnitSamples, start_ns: int | None, end_ns: int | None
                      ) -> UnitNoise | CalibrationError:
    """``unit_noise``, or the error that refused it (the caller says which unit)."""
    try:
        return unit_noise(samples, start_ns, end_ns)
    except CalibrationError as exc:
        return exc


@dataclass(frozen=True)
class _Found:
    """A worker's result for one unit: its place in the caller's list, and its noise."""

    index: int
    noise: UnitNoise | CalibrationError


def _noise_share(share: list[tuple[int, UnitSamples]], send: Callable[[_Found], None],
                 start_ns: int | None, end_ns: int | None) -> None:
    """The noise of a worker's units, sent unit by unit."""
    for index, samples in share:
        send(_Found(index, _noise_or_refusal(samples, start_ns, end_ns)))


def units_noise(units: Sequence[UnitSamples], start_ns: int | None = None,
                end_ns: int | None = None, jobs: int | None = None
                ) -> list[UnitNoise | CalibrationError]:
    """``unit_noise`` of several units, shared out among processes on the cores.

    Forked workers find the samples read here as they were; only the results come back
    (``bridge._workers``).

    Args:
        units: Their samples.
        start_ns: As ``unit_noise``.
        end_ns: As ``unit_noise``.
        jobs: Processes at once; None: one per core (one process: here).

    Returns:
        Each unit's noise, or the error that refused it, in the order given.

    Raises:
        CalibrationError: A worker process stopped (killed, out of memory).
    """
    jobs = min(len(units), max(1, (os.cpu_count() or 1) if jobs is None else jobs))
    if jobs <= 1:
        return [_noise_or_refusal(u, start_ns, end_ns) for u in units]
    shares = share_out(list(enumerate(units)), [len(u) for u in units], jobs)
    work = functools.partial(_noise_share, start_ns=start_ns, end_ns=end_ns)
    found: dict[int, UnitNoise | CalibrationError] = {}
    with Workers(work, shares, error=CalibrationError, what="noise") as sent:
        for result in sent:
            found[result.index] = result.noise
    return [found[i] for i in range(len(units))]


def _number(value: float) -> str:
    return f"{value:.6e}"


def kalibr_yaml(noise: UnitNoise, topic: str, source: str) -> str:
    """Kalibr's imu.yaml for a unit, with what else was found under ``gx3_allan``.

    Args:
        noise: The unit's noise.
        topic: Its ROS 2 IMU topic (``bridge.ros2.ros_topic``).
        source: The archive's name, for the record.

    Returns:
        The file's text.
    """
    acc, gyr = noise.accelerometer, noise.gyroscope
    lines = [
        f"# IMU noise of unit {noise.unit} for Kalibr (imu.yaml), read off the Allan "
        "deviation by gx3 allan:",
        "# the worst axis of each sensor; continuous-time units. Kalibr's wiki advises",
        "# inflating these for a unit in motion (vibration, temperature).",
        "",
        "#Accelerometers",
        f"accelerometer_noise_density: {_number(acc.noise_density)}  # m/s^2/sqrt(Hz)",
        f"accelerometer_random_walk: {_number(acc.random_walk)}  # m/s^3/sqrt(Hz)",
        "",
        "#Gyroscopes",
        f"gyroscope_noise_density: {_number(gyr.noise_density)}  # rad/s/sqrt(Hz)",
        f"gyroscope_random_walk: {_number(gyr.random_walk)}  # rad/s^2/sqrt(Hz)",
        "",
        f"rostopic: {topic}",
        f"update_rate: {noise.rate_hz:.6g}  # Hz",
        "",
        "# Not read by Kalibr: each axis, bias instability (the flat minimum of the",
        "# deviation over 0.664, IEEE Std 952) and its averaging time, what was used.",
        "gx3_allan:",
        f"  unit: {noise.unit}",
        f"  source: {source}",
    ]
    for sensor in (acc, gyr):
        lines.append(f"  {sensor.sensor}:  # {sensor.unit}")
        for key, values in (
                ("noise_density", [a.noise_density for a in sensor.axes]),
                ("random_walk", [a.random_walk for a in sensor.axes]),
                ("random_walk_sigma", [a.random_walk_sigma for a in sensor.axes]),
                ("random_walk_upper_bound", [a.walk_bound for a in sensor.axes]),
                ("bias_instability", [a.bias_instability for a in sensor.axes]),
                ("bias_instability_tau_s", [a.bias_instability_tau for a in sensor.axes])):
            shown = ", ".join(str(v).lower() if isinstance(v, bool) else _number(v)
                              for v in values)
            lines.append(f"    {key}: [{shown}]  # x, y, z")
    finite = noise.tau[np.isfinite(noise.gyroscope.adev).all(axis=0)]
    first, last = noise.stretches[0][0], noise.stretches[-1][1]
    lines += [
        f"  tau_s: [{_number(float(finite[0]))}, {_number(float(finite[-1]))}]",
        f"  span: {{start: {utc_text(first)}, end: {utc_text(last)}}}",
        f"  samples_used: {noise.used_samples}",
        f"  samples_in_span: {noise.samples}",
        f"  seconds_used: {noise.used_seconds:.1f}",
        f"  stretches: {len(noise.stretches)}",
        "  warnings: [" + ", ".join(_quoted(w) for w in noise.warnings) + "]",
    ]
    return "\n".join(lines) + "\n"


def _quoted(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def stretch_text(noise: UnitNoise) -> str:
    """How much of the span was used, in words.

    Args:
        noise: The unit's noise.

    Returns:
        One line: samples and hours used, and in how many stretches.
    """
    return (f"{number(noise.used_samples)} of {counted(noise.samples, 'sample')} "
            f"({noise.used_seconds / 3600:.2f} h at {noise.rate_hz:.4g} Hz) in "
            f"{counted(len(noise.stretches), 'contiguous stretch', 'contiguous stretches')}")

