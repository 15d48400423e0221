"""A still unit's IMU noise from an archive: what Kalibr, VINS and OpenVINS ask for.

The archive is read once, chunk by chunk (``read_archive``'s ``on_blocks``): of each
unit asked for, only its accelerations and angular rates, the timer and the sample
times are kept, as float32 and integer columns (36 bytes a sample, never a Python
object each), with the filter width and decimation of each Info its bridge published;
the file's chunks are dropped as they are decoded. Each unit's samples are then
checked for motion, cut into contiguous stretches wherever its timer does not step by
one sample period mod 2**32 (a gap, a reset: never bridged; a rollover steps exactly),
and handed to ``bridge.analysis.allan`` with the unit's filter width M and decimation
D, which shape its curve; several units share the cores (``units_noise``).

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
    CYCLES_PER_S,
    MIN_FACTOR,
    AllanSums,
    NoiseFit,
    averaging_factors,
    fit_start,
    read_off,
    white_variance,
)
from bridge.archive.reader import ArchiveReader
from bridge.bus.gx3_pb2 import Info
from bridge.exceptions import CalibrationError
from bridge.protocol.convert import STANDARD_GRAVITY
from bridge.protocol.table import DEFAULT_FILTER_WIDTH, TICKS_PER_SECOND
from bridge.ros2.noise import white_equivalent_density

__all__ = ["NOISE_KEYS", "SensorNoise", "UnitNoise", "UnitSamples", "collect_samples",
           "kalibr_yaml", "stretch_text", "unit_noise", "units_noise"]

#: What Kalibr reads, in its order; the rest of the file is ours.
NOISE_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk",
              "gyroscope_noise_density", "gyroscope_random_walk")
#: Still data under which the random walks are uncertain (Kalibr's wiki: hours).
MIN_WALK_S = 3 * 3600.0
#: A still unit on earth feels gravity alone: each second's mean specific force is 1 g
#: within this, m/s² (a GX3's bias and scale errors are ten times smaller) ...
MOVED_GRAVITY = 0.5
#: ... and it turns slower than this, rad/s (3 °/s: ten times a GX3's gyro bias).
MOVED_SPIN = 0.05
#: Its one-second means also stay this close to their median over the recording: m/s²
#: and rad/s (a bias random walk's drift over hours) ...
MOVED_ACCEL = 0.1
MOVED_RATE = 0.01
#: ... or within this many times the spread of its samples, when its noise is larger.
MOVED_FACTOR = 10.0
#: A second's spread of samples this many times the median second's is motion too
#: (a knock, handling), in seconds of at least _MIN_SPREAD_SAMPLES samples.
MOVED_SPREAD = 5.0
_MIN_SPREAD_SAMPLES = 5
_AXES = "xyz"
#: Rows of a block of ``UnitSamples``'s columns: 12 MB of float32 triples.
BLOCK_SAMPLES = 1 << 20


@dataclass
class UnitSamples:
    """A unit's samples that have acceleration and angular rate, in archive order.

    Each column is a list of arrays, joined when the noise is read off. ``add`` copies
    an archive chunk's few thousand samples into blocks of ``BLOCK_SAMPLES`` rows: each
    block is then a mapping of its own, which goes back to the system when freed, where
    thousands of small arrays would leave the heap as large as they made it.

    Attributes:
        unit: The unit's name.
        time_ns: Each sample's instant, host ns.
        timer: The unit's timer at each (62.5 kHz, wraps at 2**32).
        accel: Specific force, g, (n, 3) float32.
        ang_rate: Angular rate, rad/s, (n, 3) float32.
        other_codes: Record types of the unit that lack either, and were left out.
        settings: (bring-up ns, filter width, decimation) of each Info of the unit.
    """

    unit: str
    time_ns: list[np.ndarray] = field(default_factory=list)
    timer: list[np.ndarray] = field(default_factory=list)
    accel: list[np.ndarray] = field(default_factory=list)
    ang_rate: list[np.ndarray] = field(default_factory=list)
    other_codes: set[int] = field(default_factory=set)
    settings: list[tuple[int, int, int]] = field(default_factory=list)
    # rows not yet filled at the end of each column's last block
    _room: int = field(default=0, init=False, repr=False)

    def __len__(self) -> int:
        return sum(len(t) for t in self.time_ns) - self._room

    def _columns(self) -> tuple[list[np.ndarray], ...]:
        return self.time_ns, self.timer, self.accel, self.ang_rate

    def add(self, time_ns: np.ndarray, timer: np.ndarray, accel: np.ndarray,
            ang_rate: np.ndarray) -> None:
        """Keep samples (a chunk's), copied into the columns' blocks.

        Args:
            time_ns: Their instants, int64 host ns.
            timer: Their timer values, uint32.
            accel: Their specific force, g, (n, 3).
            ang_rate: Their angular rate, rad/s, (n, 3).
        """
        values: tuple[np.ndarray, ...] = (
            time_ns.astype(np.int64, copy=False), timer.astype(np.uint32, copy=False),
            accel.astype(np.float32, copy=False), ang_rate.astype(np.float32, copy=False))
        done = 0
        while done < len(time_ns):
            if not self._room:
                for column, value in zip(self._columns(), values, strict=True):
                    column.append(np.empty((BLOCK_SAMPLES, *value.shape[1:]), value.dtype))
                self._room = BLOCK_SAMPLES
            take = min(self._room, len(time_ns) - done)
            at = BLOCK_SAMPLES - self._room
            for column, value in zip(self._columns(), values, strict=True):
                column[-1][at : at + take] = value[done : done + take]
            self._room -= take
            done += take

    def join(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each column as one array, its blocks let go (the column is kept joined).

        Returns:
            time_ns, timer, accel, ang_rate.
        """
        room, self._room = self._room, 0
        for column in self._columns():
            if room:
                column[-1] = column[-1][: len(column[-1]) - room]
            if len(column) > 1:
                column[:] = [np.concatenate(column)]
        return self.time_ns[0], self.timer[0], self.accel[0], self.ang_rate[0]


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
        infos = {c.topic: c.unit for c in archive.channels.values() if c.kind == "info"}
        for topic, name in sorted(infos.items()):
            if units is None or name in units:
                unit = kept.setdefault(name, UnitSamples(name))
                unit.settings += [(info.bring_up_time_ns, info.filter_width, info.decimation)
                                  for _, info in archive.decoded(topic, Info)]
        for block in archive.samples(units):
            unit = kept.setdefault(block.unit, UnitSamples(block.unit))
            cols = block.columns
            if "accel" not in cols or "ang_rate" not in cols:
                unit.other_codes.add(block.code)
                continue
            unit.add(cols["time_ns"], cols["timer"], cols["accel"], cols["ang_rate"])

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

    @property
    def walk_bound(self) -> bool:
        """Whether the worst axis's random walk is only an upper bound."""
        return max(self.axes, key=lambda a: a.random_walk).walk_bound

    def walk_text(self) -> str:
        """The worst axis's random walk as a person reads it: ≤ before a bound.

        Returns:
            The number, to 3 significant digits.
        """
        return ("≤ " if self.walk_bound else "") + f"{self.random_walk:.3g}"


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
        filter_width: M, the unit's filter width the curve was read with.
        decimation: D, its calculation cycles per sample.
        width_from_info: Whether M is the unit's own (its Info), not the factory's.
    """

    unit: str
    rate_hz: float
    tau: np.ndarray
    accelerometer: SensorNoise
    gyroscope: SensorNoise
    stretches: tuple[tuple[int, int, int], ...]
    samples: int
    warnings: tuple[str, ...]
    filter_width: int = DEFAULT_FILTER_WIDTH
    decimation: int = 1
    width_from_info: bool = True

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
    are averaged to give the period. Steps of the uint32 timer are taken in uint32,
    whose arithmetic wraps as the timer does: a rollover's step is exact.
    """
    steps: np.ndarray = np.diff(timer.astype(np.uint32, copy=False))
    if not len(steps):
        return steps, 0.0
    median = float(np.median(steps))
    regular = (steps >= median - 1.0) & (steps <= median + 1.0)
    return steps, float(np.mean(steps, where=regular, dtype=np.float64))


def _stretch_bounds(steps: np.ndarray, step: float) -> np.ndarray:
    """Where each contiguous stretch starts, and the end.

    A stretch is cut wherever the timer does not move on by one period mod 2**32: a
    gap, a repeat, a reset. A rollover moves on by exactly one period mod 2**32, and
    cuts nothing.
    """
    cut = (steps < step - 1.0) | (steps > step + 1.0)
    return np.concatenate([[0], np.flatnonzero(cut) + 1, [len(steps) + 1]])


def _span(samples: UnitSamples, start_ns: int | None, end_ns: int | None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The unit's samples from ``start_ns`` to before ``end_ns``, in time order.

    Returns:
        time_ns, timer, accel (g) and ang_rate, views of the joined columns when the
        archive held them in time order (as a recording does).
    """
    time_ns, timer, accel, rate = samples.join()
    if len(time_ns) > 1 and (time_ns[1:] < time_ns[:-1]).any():
        order = np.argsort(time_ns, kind="stable")
        time_ns, timer, accel, rate = time_ns[order], timer[order], accel[order], rate[order]
    lo = 0 if start_ns is None else int(np.searchsorted(time_ns, start_ns))
    hi = len(time_ns) if end_ns is None else int(np.searchsorted(time_ns, end_ns))
    return time_ns[lo:hi], timer[lo:hi], accel[lo:hi], rate[lo:hi]


def _filter_width(samples: UnitSamples, first_ns: int, last_ns: int) -> int | None:
    """The unit's filter width over its samples from ``first_ns`` to ``last_ns``.

    From the Info in effect at the first (the last published before it, or else the
    first after it); None when the archive holds none.

    Raises:
        CalibrationError: The width or the decimation changed within the span.
    """
    settings = sorted(samples.settings)
    if not settings:
        return None
    before = [s for s in settings if s[0] <= first_ns]
    current = before[-1] if before else settings[0]
    for at_ns, width, decimation in settings:
        if first_ns < at_ns <= last_ns and (width, decimation) != current[1:]:
            raise CalibrationError(
                f"unit {samples.unit}'s filter width and decimation changed from "
                f"{current[1]} and {current[2]} to {width} and {decimation} at "
                f"{utc_text(at_ns)}; they shape its noise: give --start/--end around one "
                "setting")
    return current[1]


def _second_sums(time_ns: np.ndarray, parts: tuple[np.ndarray, ...]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per second of samples (in time order): where it starts and its samples.

    Also the sums of the columns of ``parts``, in order, then the sums of their squares,
    in float64 whatever the columns' type.
    """
    ends = np.arange(time_ns[0], time_ns[-1] + 1, 1_000_000_000, dtype=np.int64)
    starts = np.unique(np.searchsorted(time_ns, ends))
    counts = np.diff(np.concatenate([starts, [len(time_ns)]]))
    columns = [part[:, i] for part in parts for i in range(part.shape[1])]
    sums = [np.add.reduceat(c, starts, dtype=np.float64) for c in columns]
    squares = [np.add.reduceat(np.square(c, dtype=np.float64), starts) for c in columns]
    return starts, counts, np.column_stack(sums + squares)


def _moved(time_ns: np.ndarray, accel: np.ndarray, rate: np.ndarray, unit: str) -> None:
    """Refuse samples in which the unit moved, naming when.

    Per second of samples, against what any still unit on earth does (its mean specific
    force is 1 g, it does not turn), against the recording's own median (its still
    value, unless it moved throughout, which the first test catches), and the spread
    within the second against the median second's (a knock). Samples with a NaN are
    left out of the judging, never let it pass.
    """
    finite = np.isfinite(accel).all(axis=1) & np.isfinite(rate).all(axis=1)
    if not finite.all():
        keep = np.flatnonzero(finite)
        time_ns, accel, rate = time_ns[keep], accel[keep], rate[keep]
    if not len(time_ns):
        return
    starts, counts, sums = _second_sums(time_ns, (accel, rate))
    mean = sums[:, :6] / counts[:, None]
    mean[:, :3] *= STANDARD_GRAVITY
    spread = np.sqrt((sums[:, 6:] / counts[:, None] - (sums[:, :6] / counts[:, None]) ** 2
                      ).clip(0))
    spread[:, :3] *= STANDARD_GRAVITY
    f_spread = np.linalg.norm(spread[:, :3], axis=1)
    r_spread = np.linalg.norm(spread[:, 3:], axis=1)
    gravity_off = np.abs(np.linalg.norm(mean[:, :3], axis=1) - STANDARD_GRAVITY)
    turning = np.linalg.norm(mean[:, 3:], axis=1)
    f_off = np.linalg.norm(mean[:, :3] - np.median(mean[:, :3], axis=0), axis=1)
    r_off = np.linalg.norm(mean[:, 3:] - np.median(mean[:, 3:], axis=0), axis=1)
    moved = ((gravity_off > MOVED_GRAVITY) | (turning > MOVED_SPIN)
             | (f_off > max(MOVED_ACCEL, MOVED_FACTOR * float(np.median(f_spread))))
             | (r_off > max(MOVED_RATE, MOVED_FACTOR * float(np.median(r_spread)))))
    full = counts >= _MIN_SPREAD_SAMPLES
    if full.any():
        for second_spread in (f_spread, r_spread):
            typical = float(np.median(second_spread[full]))
            moved |= full & (second_spread > MOVED_SPREAD * typical) & (typical > 0)
    if not moved.any():
        return
    seconds = np.flatnonzero(moved)
    start = int(starts[seconds[0]])
    end = int(starts[seconds[-1]] + counts[seconds[-1]] - 1)
    first_s = (time_ns[start] - time_ns[0]) / 1e9
    last_s = (time_ns[end] - time_ns[0]) / 1e9
    raise CalibrationError(
        f"unit {unit} moved from {utc_text(int(time_ns[start]))} to "
        f"{utc_text(int(time_ns[end]))} "
        f"({first_s:.0f} s to {last_s:.0f} s into the span, {len(seconds)} s with motion: "
        f"specific force up to {float(max(f_off.max(), gravity_off.max())):.3g} m/s² off "
        f"its still value, turning up to {float(max(r_off.max(), turning.max())):.3g} "
        "rad/s); the noise needs a unit that stays still: record again without touching "
        "it, or give --start/--end around a still stretch")


def _warnings(noise_seconds: float, fits: list[NoiseFit], left_out: int, total: int,
              width: int, decimation: int, width_from_info: bool) -> list[str]:
    """What a person should know of a unit's read-off, in words."""
    warnings = []
    if not width_from_info:
        warnings.append(f"the archive holds no Info giving the unit's filter width: the "
                        f"factory's, {width}, was assumed; the densities depend on it: "
                        "record with gx3 record or gx3 replay, which keep the unit's Info")
    if noise_seconds < MIN_WALK_S:
        warnings.append(
            f"only {noise_seconds / 3600:.2g} h of still data: the noise densities hold, "
            "but the random walks need hours (" + ", ".join(
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
    if decimation > width:
        rate = CYCLES_PER_S / decimation
        equivalent = white_equivalent_density(1.0, rate, width)
        warnings.append(
            f"its decimation ({decimation}) is larger than its filter width ({width}): "
            f"each sample averages {width} of every {decimation} ms and misses the rest, "
            f"so its samples carry {equivalent:.3g} times the sensor's noise density at "
            f"{rate:g} Hz; the file holds the sensor's (gx3 export --noise and gx3 bridge "
            f"--noise allow for it); give Kalibr, VINS or OpenVINS the densities times "
            f"{equivalent:.3g}, or set the filter width to {decimation} or more")
    if left_out:
        warnings.append(f"{left_out} of {total} samples left out: stretches of "
                        f"fewer than {2 * MIN_FACTOR} samples between gaps, or NaN values")
    return warnings


def unit_noise(samples: UnitSamples, start_ns: int | None = None,
               end_ns: int | None = None) -> UnitNoise:
    """A unit's Allan deviation and its noise, from its archived samples.

    Args:
        samples: The unit's samples (``collect_samples``); their chunks are joined.
        start_ns: Only samples at or after this (host ns).
        end_ns: Only samples before this.

    Returns:
        Its noise, and what it was read from.

    Raises:
        CalibrationError: No samples with accel and rate in the span, too few to average,
            the unit moved, its filter settings changed within the span, or its curve
            shows no white noise.
    """
    name = samples.unit
    if not len(samples):
        kinds = ", ".join(f"0x{c:02X}" for c in sorted(samples.other_codes)) or "none"
        raise CalibrationError(
            f"unit {name} has no samples with both acceleration and angular rate (record "
            f"types it has: {kinds}); stream a type with both, such as 0xC2, 0xC8 or 0xCC")
    time_ns, timer, accel, rate = _span(samples, start_ns, end_ns)
    if len(time_ns) < 2 * MIN_FACTOR:
        raise CalibrationError(f"unit {name}: {len(time_ns)} samples from --start to --end; "
                               "the noise needs minutes of a still unit, hours for the "
                               "random walks")
    _moved(time_ns, accel, rate, name)
    steps, step = _sample_step(timer)
    period = step / TICKS_PER_SECOND
    decimation = max(1, round(period * CYCLES_PER_S))
    known = _filter_width(samples, int(time_ns[0]), int(time_ns[-1]))
    width = DEFAULT_FILTER_WIDTH if known is None else known
    bounds = _stretch_bounds(steps, step)
    spans = [(a, b) for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)
             if b - a >= 2 * MIN_FACTOR]
    if not spans:
        raise CalibrationError(f"unit {name}: no stretch of {2 * MIN_FACTOR} samples without "
                               "a gap; record the still unit for minutes without interruption")
    sums = AllanSums(averaging_factors(max(b - a for a, b in spans)), 6)
    finite = np.isfinite(accel).all(axis=1) & np.isfinite(rate).all(axis=1)
    used = []
    for a, b in spans:
        # a NaN (a unit sending none) cuts a stretch like a gap
        inner = np.flatnonzero(~finite[a:b]) + a
        for lo, hi in zip([a, *(inner + 1).tolist()], [*inner.tolist(), b], strict=True):
            if hi - lo >= 2 * MIN_FACTOR:
                sums.add(accel[lo:hi], rate[lo:hi])
                used.append((int(time_ns[lo]), int(time_ns[hi - 1]), hi - lo))
    tau = sums.factors * period
    avar = sums.variance()
    avar[:, :3] *= STANDARD_GRAVITY**2  # the accelerometer's from g to m/s²
    adev = np.sqrt(avar).T
    white = white_variance(sums.factors, width, decimation)
    start = fit_start(width, decimation)
    fits = [read_off(tau, avar[:, i], sums.averages(), white, start) for i in range(6)]
    for i, fit in enumerate(fits):
        if not fit.noise_density > 0:
            sensor = ("accelerometer", "gyroscope")[i // 3]
            raise CalibrationError(
                f"unit {name}: no white noise shows in the {sensor} {_AXES[i % 3]} (its "
                f"Allan deviation does not fall as 1/√τ from {start:g} s on), so it has no "
                "noise density to give: the unit moved slowly, or its readings hardly "
                "change; record it still and streaming")
    warnings = _warnings(sums.samples * period, fits, len(time_ns) - sums.samples,
                         len(time_ns), width, decimation, known is not None)
    return UnitNoise(
        unit=name, rate_hz=1.0 / period, tau=tau,
        accelerometer=SensorNoise("accelerometer", "m/s^2", adev[0:3],
                                  (fits[0], fits[1], fits[2])),
        gyroscope=SensorNoise("gyroscope", "rad/s", adev[3:6], (fits[3], fits[4], fits[5])),
        stretches=tuple(used), samples=len(time_ns), warnings=tuple(warnings),
        filter_width=width, decimation=decimation, width_from_info=known is not None)


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
        "# the worst axis of each sensor; the sensor's own, in continuous-time units, whatever",
        "# the rate and filter width. Kalibr's wiki advises inflating these for a unit in",
        "# motion (vibration, temperature).",
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
        "# deviation over 0.664, IEEE Std 952) and its averaging time, the unit's filter",
        "# (M cycles averaged, every D-th sent) the fit modelled, what was used.",
        "gx3_allan:",
        f"  unit: {noise.unit}",
        f"  source: {source}",
        f"  filter_width: {noise.filter_width}  # M: "
        + ("the unit's Info" if noise.width_from_info else "assumed, the factory's"),
        f"  decimation: {noise.decimation}  # D: 1000 Hz / update_rate",
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
    fitted = [fit.fit_tau for sensor in (acc, gyr) for fit in sensor.axes]
    lines += [
        f"  tau_s: [{_number(float(finite[0]))}, {_number(float(finite[-1]))}]",
        f"  fit_tau_s: [{_number(min(f[0] for f in fitted))}, "
        f"{_number(max(f[1] for f in fitted))}]  # from 10 x (M + D) ms, 50 ms at least",
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

