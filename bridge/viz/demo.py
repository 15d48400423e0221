"""Demo columns for the viewer: the emulator's motion model, through the bus codec.

The columns are what a subscriber decodes from ImuSample bytes (float32 quantities,
uint32 timer, int64 ticks and times), so tests, benchmarks and screenshots exercise the
logger with data shaped exactly like the real thing.
"""

from __future__ import annotations

import os

import numpy as np

from bridge.bus.codec import decode_batch, encode_batch, record_quantities
from bridge.bus.gx3_pb2 import Event, Status
from bridge.protocol.codec import Batch
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.sim.motion import Motion, MotionConfig
from bridge.viz.logger import RerunLogger

#: 2025-11-01 00:00:00 UTC, in ns: where demo host time starts.
DEMO_EPOCH_NS = 1_761_955_200_000_000_000


def demo_columns(unit: str, code: int, seed: int, seconds: float, rate_hz: float = 100.0,
                 start_s: float = 0.0, drift_ppm: float = 0.0) -> dict[str, np.ndarray]:
    """``seconds`` of one unit's ``code`` records from ``start_s`` of device time on.

    As decode_batch returns them; time_ns is device time divided by 1 + drift_ppm * 1e-6
    (a unit whose clock runs fast by drift_ppm), as in the Status clock model.
    """
    n = round(seconds * rate_hz)
    ticks = round(start_s * TICKS_PER_SECOND) + np.arange(n, dtype=np.int64) * round(
        TICKS_PER_SECOND / rate_hz)
    device_s = ticks / TICKS_PER_SECOND
    truth = Motion(MotionConfig(seed=seed, noise_accel_g=0.002, noise_gyro_rad_s=0.002,
                                noise_mag_gauss=0.001)).sample(device_s, 1.0 / rate_hz)
    values = {q: truth[q] for q in record_quantities(code)}
    values["timer"] = (ticks & 0xFFFF_FFFF).astype(np.uint32)
    time_ns = DEMO_EPOCH_NS + np.round(device_s * 1e9 / (1.0 + drift_ppm * 1e-6)).astype(np.int64)
    rx_ns = time_ns + 2_000_000
    batch = Batch(code, values, np.arange(n), rx_ns, False)
    payloads = encode_batch(unit, batch, ticks, time_ns, rx_ns)
    return decode_batch(unit, code, payloads)


#: The demo fleet: unit name, record type, motion seed, clock drift [ppm].
DEMO_FLEET = (("imu0", 0xCC, 1, 12.0), ("imu1", 0xCC, 2, -8.0), ("imu2", 0xC8, 3, 25.0))


def _statuses(unit: str, code: int, seed: int, drift: float, rate_hz: float,
              device_s: np.ndarray, kept: np.ndarray) -> list[Status]:
    """One status a second, as a bridge would publish.

    Counts from the records kept, a clock model that settles on the unit's drift.
    """
    rng = np.random.default_rng(seed)
    out = []
    for s in range(1, int(device_s[-1]) + 1):
        before = device_s < s
        out.append(Status(
            unit=unit, time_ns=DEMO_EPOCH_NS + round(s * 1e9 / (1 + drift * 1e-6)),
            connected=True, state=Status.STREAMING, command=code, output_rate_hz=rate_hz,
            samples_per_s=float(kept[before & (device_s >= s - 1)].sum()),
            samples=int(kept[before].sum()), dropped=int((~kept)[before].sum()),
            clock_offset_ns=DEMO_EPOCH_NS + round(rng.normal(0.0, 50_000.0) / s),
            clock_drift_ppm=drift + float(rng.normal(0.0, 3.0)) / s))
    return out


def write_demo(path: str | os.PathLike[str], seconds: float = 30.0, rate_hz: float = 100.0,
               gap_s: tuple[float, float] = (12.0, 12.5)) -> None:
    """A recording of DEMO_FLEET: samples, status, bring-up events, and a gap in imu1.

    Its records from gap_s[0] to gap_s[1] are missing, and a GAP event says so.
    """
    with RerunLogger(path, [unit for unit, *_ in DEMO_FLEET], recording_id="demo") as log:
        for unit, code, seed, drift in DEMO_FLEET:
            cols = demo_columns(unit, code, seed, seconds, rate_hz, drift_ppm=drift)
            device_s = cols["ticks"] / TICKS_PER_SECOND
            kept = np.ones(len(device_s), bool)
            events = [Event(unit=unit, time_ns=int(cols["time_ns"][0]) - 10**8,
                            kind=Event.BRING_UP,
                            detail=f"streaming 0x{code:02X} at {rate_hz:g} Hz")]
            if unit == "imu1":
                kept = (device_s < gap_s[0]) | (device_s >= gap_s[1])
                after = int(np.argmax(device_s >= gap_s[1]))
                jump = int(cols["ticks"][after] - cols["ticks"][after - (~kept).sum() - 1])
                events.append(Event(unit=unit, time_ns=int(cols["time_ns"][after]),
                                    ticks=int(cols["ticks"][after]), kind=Event.GAP,
                                    count=int((~kept).sum()), detail=f"ticks jumped by {jump:,}"))
            log.log_event(unit, events)
            log.log_samples(unit, code, {k: v[kept] for k, v in cols.items()})
            log.log_status(unit, _statuses(unit, code, seed, drift, rate_hz, device_s, kept))
