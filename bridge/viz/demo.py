"""Demo columns for the viewer: the emulator's motion model, through the bus codec.

The columns are what a subscriber decodes from ImuSample bytes (float32 quantities,
uint32 timer, int64 ticks and times), so tests, benchmarks and screenshots exercise the
logger with data shaped exactly like the real thing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bridge.bus.codec import decode_batch, encode_batch, record_quantities
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.sim.motion import Motion, MotionConfig

#: 2025-11-01 00:00:00 UTC, in ns: where demo host time starts.
DEMO_EPOCH_NS = 1_761_955_200_000_000_000


@dataclass
class _Batch:
    """The RecordBatch face encode_batch needs, over a dict of columns."""

    code: int
    columns: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.columns["timer"])

    def __getitem__(self, name: str, /) -> np.ndarray:
        return self.columns[name]


def demo_columns(unit: str, code: int, seed: int, seconds: float, rate_hz: float = 100.0,
                 start_s: float = 0.0, drift_ppm: float = 0.0) -> dict[str, np.ndarray]:
    """``seconds`` of one unit's ``code`` records from ``start_s`` of device time on, as
    decode_batch returns them; host time runs ``drift_ppm`` slower than the device clock."""
    n = round(seconds * rate_hz)
    ticks = round(start_s * TICKS_PER_SECOND) + np.arange(n, dtype=np.int64) * round(
        TICKS_PER_SECOND / rate_hz)
    device_s = ticks / TICKS_PER_SECOND
    truth = Motion(MotionConfig(seed=seed, noise_accel_g=0.002, noise_gyro_rad_s=0.002,
                                noise_mag_gauss=0.001)).sample(device_s, 1.0 / rate_hz)
    values = {q: truth[q] for q in record_quantities(code)}
    values["timer"] = (ticks & 0xFFFF_FFFF).astype(np.uint32)
    time_ns = DEMO_EPOCH_NS + np.round(device_s * 1e9 * (1.0 + drift_ppm * 1e-6)).astype(np.int64)
    payloads = encode_batch(unit, _Batch(code, values), ticks, time_ns, time_ns + 2_000_000)
    return decode_batch(unit, code, payloads)
