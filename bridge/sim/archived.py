"""A unit's samples in virtual time, straight into an archive: hours of a unit in seconds.

What a bridge would have archived from a unit streaming 0xC2 (acceleration and angular
rate), its values from the emulator's motion model (noise, bias random walk) through
the unit's filters at the given device times, without a link, a port or real time in
between: for analyses that need hours of a still unit (``gx3 allan``), their tests and
benchmarks. Leave device times out for a gap; give a timer that restarts or wraps for a
reset or a rollover.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.bus.codec import encode_batch
from bridge.bus.gx3_pb2 import Info
from bridge.protocol.codec import Batch
from bridge.protocol.table import DEFAULT_FLAGS, TICKS_PER_SECOND, Flag
from bridge.sim.motion import CYCLES_PER_S, Motion, SignalChain
from bridge.sim.state import Sampling

if TYPE_CHECKING:
    from bridge.archive.writer import ArchiveWriter

__all__ = ["archive_samples"]

_CODE = 0xC2
_BATCH = 50_000  # samples encoded at once: bounds the memory of hours of them
#: A unit as it leaves the factory: 0xDB's default widths, coning and sculling on.
FACTORY_CHAIN = SignalChain(Sampling.filter_width, Sampling.mag_filter_width,
                            bool(DEFAULT_FLAGS & Flag.CONING_SCULLING))


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
    decimation = max(1, round(period * CYCLES_PER_S))
    if len(times):
        at_ns = wall_ns + round(float(times[0]) * 1e9)
        info = Info(unit=unit, command=_CODE, decimation=decimation,
                    filter_width=chain.filter_width, mag_filter_width=chain.mag_filter_width,
                    flags=Flag.CONING_SCULLING if chain.coning_sculling else 0,
                    output_rate_hz=CYCLES_PER_S / decimation, bring_up_time_ns=at_ns)
        writer.write(f"{writer.prefix}/{unit}/info", info.SerializeToString(), at_ns)
    for at in range(0, len(times), _BATCH):
        t = times[at : at + _BATCH]
        sample = motion.sample(t, period, chain, only=("accel", "ang_rate"))
        ticks = timer_start + np.round(t * TICKS_PER_SECOND).astype(np.int64)
        columns = {"timer": (ticks % (1 << 32)).astype(np.uint32),
                   "accel": sample["accel"].astype(np.float32),
                   "ang_rate": sample["ang_rate"].astype(np.float32)}
        time_ns = wall_ns + np.round(t * 1e9).astype(np.int64)
        batch = Batch(_CODE, columns, np.arange(len(t)), time_ns, False)
        writer.write_many(f"{writer.prefix}/{unit}/imu",
                          encode_batch(unit, batch, ticks, time_ns, time_ns), time_ns)
