"""A unit's samples in virtual time, straight into an archive: hours of a unit in seconds.

What a bridge would have archived from a unit streaming 0xC2 (acceleration and angular
rate), its values from the emulator's motion model (noise, bias random walk) at the
given device times, without a link, a port or real time in between: for analyses that
need hours of a still unit (``gx3 allan``), their tests and benchmarks. Leave device
times out for a gap; give a timer that restarts or wraps for a reset or a rollover.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from bridge.bus.codec import encode_batch
from bridge.protocol.codec import Batch
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.sim.motion import Motion

if TYPE_CHECKING:
    from bridge.archive.writer import ArchiveWriter

__all__ = ["archive_samples"]

_CODE = 0xC2
_BATCH = 50_000  # samples encoded at once: bounds the memory of hours of them


def archive_samples(writer: ArchiveWriter, unit: str, motion: Motion,
                    device_s: npt.ArrayLike, period: float, *, timer_start: int = 0,
                    wall_ns: int = 1_763_000_000_000_000_000) -> None:
    """Archive the 0xC2 samples a unit sends at ``device_s``, as its bridge publishes them.

    Args:
        writer: The archive (its key prefix is the unit's).
        unit: The unit's name.
        motion: What the unit experiences.
        device_s: Device times of the samples [s], ascending.
        period: The output sample period [s] (the noise densities are per its root).
        timer_start: The timer at device time 0 (mod 2**32: a value near the top crosses
            the rollover; a later call with another start is a reset).
        wall_ns: Host time at device time 0: a sample's time is this plus its device time.
    """
    times = np.asarray(device_s, np.float64)
    for at in range(0, len(times), _BATCH):
        t = times[at : at + _BATCH]
        sample = motion.sample(t, period, only=("accel", "ang_rate"))
        ticks = timer_start + np.round(t * TICKS_PER_SECOND).astype(np.int64)
        columns = {"timer": (ticks % (1 << 32)).astype(np.uint32),
                   "accel": sample["accel"].astype(np.float32),
                   "ang_rate": sample["ang_rate"].astype(np.float32)}
        time_ns = wall_ns + np.round(t * 1e9).astype(np.int64)
        batch = Batch(_CODE, columns, np.arange(len(t)), time_ns, False)
        writer.write_many(f"{writer.prefix}/{unit}/imu",
                          encode_batch(unit, batch, ticks, time_ns, time_ns), time_ns)
