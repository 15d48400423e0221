"""A unit's samples in virtual time, straight into an archive: hours of a unit in seconds.

What a bridge would have archived from a unit streaming 0xC2 (acceleration and angular
rate), its values from the emulator's motion model (noise, bias random walk) through
the unit's filters at the given device times, without a link, a port or real time in
between: for analyses that need hours of a still unit (``gx3 allan``), their tests and
benchmarks. Leave device times out for a gap; give a timer that restarts or wraps for a
reset or a rollover. ``fleet_archive`` writes a whole fleet's day the same way, with
what a recorder archives beside the samples (Info, a status a second, the bring-up),
for the viewers' tests and benchmarks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.bus.codec import encode_batch, record_quantities
from bridge.bus.gx3_pb2 import Event, Info, Status
from bridge.protocol.codec import Batch
from bridge.protocol.table import DEFAULT_FLAGS, TICKS_PER_SECOND, Flag
from bridge.sim.motion import CYCLES_PER_S, Motion, MotionConfig, SignalChain
from bridge.sim.state import Sampling

if TYPE_CHECKING:
    from bridge.archive.writer import ArchiveWriter

__all__ = ["archive_samples", "fleet_archive"]

_CODE = 0xC2
_BATCH = 50_000  # samples encoded at once: bounds the memory of hours of them
#: A unit as it leaves the factory: 0xDB's default widths, coning and sculling on.
FACTORY_CHAIN = SignalChain(Sampling.filter_width, Sampling.mag_filter_width,
                            bool(DEFAULT_FLAGS & Flag.CONING_SCULLING))
#: Seconds of each unit written in turn by ``fleet_archive``; the writer waits twice as
#: long for samples logged before others, so the archive stays in log-time order.
_STEP_S = 10.0
#: How long after its instant a sample reaches the recorder, in ``fleet_archive``.
_LATENCY_NS = 2_000_000


def archive_samples(writer: ArchiveWriter, unit: str, motion: Motion,
                    device_s: npt.ArrayLike, period: float, *, timer_start: int = 0,
                    wall_ns: int = 1_763_000_000_000_000_000,
                    chain: SignalChain = FACTORY_CHAIN) -> None:
    """Archive the 0xC2 samples a unit sends at ``device_s``, as its bridge publishes them.

    First the unit's Info, as a bridge publishes it at bring-up (its decimation and
    filter widths), then the samples.

    Args:
        writer: The archive (its key prefix is the unit's).
        unit: The unit's name.
        motion: What the unit experiences.
        device_s: Device times of the calculation cycles the samples are sent at [s],
            ascending, on the 1 ms grid.
        period: The output sample period [s]: the decimation's cycles.
        timer_start: The timer at device time 0 (mod 2**32: a value near the top crosses
            the rollover; a later call with another start is a reset).
        wall_ns: Host time at device time 0: a sample's time is this plus its device time.
        chain: The unit's filters; the factory's unless given.
    """
    times = np.asarray(device_s, np.float64)
    if len(times):
        _write_info(writer, unit, _CODE, period, chain, wall_ns + round(float(times[0]) * 1e9))
    for at in range(0, len(times), _BATCH):
        _write_samples(writer, unit, motion, times[at : at + _BATCH], period, _CODE, chain,
                       timer_start, wall_ns, 0)


def _write_info(writer: ArchiveWriter, unit: str, code: int, period: float,
                chain: SignalChain, at_ns: int) -> None:
    """Archive the Info a bridge publishes at bring-up (``at_ns``): its rate and filters."""
    decimation = max(1, round(period * CYCLES_PER_S))
    info = Info(unit=unit, command=code, decimation=decimation,
                filter_width=chain.filter_width, mag_filter_width=chain.mag_filter_width,
                flags=Flag.CONING_SCULLING if chain.coning_sculling else 0,
                output_rate_hz=CYCLES_PER_S / decimation, bring_up_time_ns=at_ns)
    writer.write(f"{writer.prefix}/{unit}/info", info.SerializeToString(), at_ns)


def _write_samples(writer: ArchiveWriter, unit: str, motion: Motion, t: np.ndarray,
                   period: float, code: int, chain: SignalChain, timer_start: int,
                   wall_ns: int, latency_ns: int) -> None:
    """Archive the ``code`` samples at device times ``t``, received ``latency_ns`` later."""
    quantities = record_quantities(code)
    sample = motion.sample(t, period, chain, only=quantities)
    ticks = timer_start + np.round(t * TICKS_PER_SECOND).astype(np.int64)
    columns = {"timer": (ticks % (1 << 32)).astype(np.uint32),
               **{q: sample[q].astype(np.float32) for q in quantities}}
    time_ns = wall_ns + np.round(t * 1e9).astype(np.int64)
    batch = Batch(code, columns, np.arange(len(t)), time_ns, False)
    received = time_ns + latency_ns
    writer.write_many(f"{writer.prefix}/{unit}/imu",
                      encode_batch(unit, batch, ticks, time_ns, received), received)


def fleet_archive(path: Path, units: Sequence[str], seconds: float, rate_hz: float, *,
                  code: int = 0xCC, wall_ns: int = 1_763_000_000_000_000_000,
                  progress: Callable[[float], None] | None = None) -> None:
    """Write an archive of a fleet streaming for ``seconds``, as ``gx3 record`` would have.

    Each unit moves and is noisy as the emulator's motion model makes it (a seed each),
    through the factory's filters, sends ``code`` records at ``rate_hz`` from ``wall_ns``
    on, and has its Info, a BRING_UP event just before its first sample, and a Status
    each second. A day of a fleet takes minutes, not a day.

    Args:
        path: The archive to create.
        units: The units' names.
        seconds: How long they stream.
        rate_hz: Their output rate.
        code: Their record type.
        wall_ns: Host time of the first samples.
        progress: Hears the seconds written so far, after each step.
    """
    from bridge.archive.writer import ArchiveWriter

    motions = [Motion(MotionConfig(seed=i + 1, noise_accel_g=0.002, noise_gyro_rad_s=0.002,
                                   noise_mag_gauss=0.001)) for i in range(len(units))]
    period = 1.0 / rate_hz
    with ArchiveWriter(path, reorder_s=2 * _STEP_S) as writer:
        for unit in units:
            up = wall_ns - 500_000_000
            _write_info(writer, unit, code, period, FACTORY_CHAIN, up)
            event = Event(unit=unit, time_ns=up, kind=Event.BRING_UP,
                          detail=f"streaming 0x{code:02X} at {rate_hz:g} Hz")
            writer.write(f"{writer.prefix}/{unit}/event", event.SerializeToString(), up)
        for start in np.arange(0.0, seconds, _STEP_S).tolist():
            first, last = round(start * rate_hz), round(min(start + _STEP_S, seconds) * rate_hz)
            t = np.arange(first, last) * period
            beats = np.arange(int(start) + 1, int(min(start + _STEP_S, seconds)) + 1)
            for k, (unit, motion) in enumerate(zip(units, motions, strict=True)):
                _write_samples(writer, unit, motion, t, period, code, FACTORY_CHAIN, 0,
                               wall_ns, _LATENCY_NS)
                statuses = [Status(
                    unit=unit, time_ns=wall_ns + s * 1_000_000_000, connected=True,
                    state=Status.STREAMING, command=code, output_rate_hz=rate_hz,
                    samples_per_s=rate_hz, samples=round(s * rate_hz),
                    clock_offset_ns=wall_ns + 1000 * k, clock_drift_ppm=10.0 + k,
                    clock_spread_ns=50_000.0).SerializeToString() for s in beats.tolist()]
                if statuses:
                    writer.write_many(f"{writer.prefix}/{unit}/status", statuses,
                                      wall_ns + beats * 1_000_000_000 + _LATENCY_NS)
            if progress is not None:
                progress(last / rate_hz)
