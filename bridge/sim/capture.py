"""Raw captures in virtual time: what a bridge would have read from one unit.

A unit streaming from power-up is run through a USB delivery model for a given
stretch of virtual time. The result is what the bridge records (the bytes of each
read and its host receive time) next to the emulator's truth for every record,
so the timing layer can be scored against the real sample instants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from bridge.protocol.table import CALCULATION_CYCLE_S, REPLIES, Mode
from bridge.sim.state import Sampling
from bridge.sim.unit import SimUnit, UnitConfig
from bridge.sim.usb import UsbDelivery, UsbLink

#: USB full speed moves about 1 MB/s of payload; the unit's line is paced at baud/10.
USB_BAUD = 10_000_000
WALL_NS = 1_763_000_000_000_000_000  # where virtual host time 0 sits on the wall clock


@dataclass
class Capture:
    """Reads (receive time, bytes) and the truth of every record sent, oldest first."""

    rx_ns: np.ndarray  # int64, one per read
    data: list[bytes]
    code: int
    truth: dict[str, np.ndarray]  # timer, time_ns, value_ns when the emulator has it, ...
    config: UnitConfig
    usb: UsbDelivery

    @property
    def true_ns(self) -> np.ndarray:
        """The instant each record's values describe (after the filter delay)."""
        return self.truth.get("value_ns", self.truth["time_ns"])


def streaming_config(config: UnitConfig, code: int = 0xC2, decimation: int = 10,
                     filter_width: int | None = None) -> UnitConfig:
    """``config`` with a stored preset that streams ``code`` from power-up over USB."""
    s = config.stored
    sampling = replace(s.sampling, decimation=decimation,
                       filter_width=s.sampling.filter_width if filter_width is None
                       else filter_width)
    stored = replace(s, mode_preset=int(Mode.CONTINUOUS), continuous_preset=code,
                     baud=USB_BAUD, sampling=Sampling(**vars(sampling)))
    return replace(config, stored=stored)


def synthesize(config: UnitConfig, usb: UsbDelivery, seconds: float,
               start: float = 0.0) -> Capture:
    """Run a unit that streams from power-up at host time ``start`` for ``seconds``.

    Only the frames in which a record's bytes can finish are polled (the next
    record's instant is known from the decimation), which keeps 10 minutes of
    100 Hz output to a couple of seconds of CPU.
    """
    code = config.stored.continuous_preset
    if config.stored.mode_preset != Mode.CONTINUOUS or code not in REPLIES:
        raise ValueError("synthesize needs a unit that streams from power-up: "
                         "build its config with streaming_config()")
    period = config.stored.sampling.decimation * CALCULATION_CYCLE_S
    size = REPLIES[code].length
    n_records = int(seconds / period) + 2
    config = replace(config, truth_length=n_records + 16)
    unit = SimUnit(config, now=start, wall_ns=WALL_NS)
    link = UsbLink(usb, start)
    rate = config.stored.baud / 10.0
    reads: list[tuple[float, bytes]] = []
    end = start + seconds
    sent = 0
    device0 = None
    frame = link.frame_at(start)
    while frame <= end:
        data = unit.poll(frame)
        link.push(data, frame)
        sent += len(data)
        reads += link.reads(frame)
        if device0 is None:
            if len(unit.truth):
                device0 = float(unit.truth.arrays()["device_s"][0])
            frame += usb.frame_s
            continue
        # Skip to the frames in which the next record's bytes finish.
        n = math.ceil(sent / size)
        t0 = float(unit.host_time(device0 + n * period))
        frame = max(frame + usb.frame_s, link.frame_at(t0 - 1e-6))
        last = link.frame_at(t0 + size / rate + 1e-6)
        while frame <= min(last, end):
            data = unit.poll(frame)
            link.push(data, frame)
            sent += len(data)
            reads += link.reads(frame)
            frame += usb.frame_s
    reads += link.reads(end + 1.0)  # what was on its way when the capture stopped
    truth = unit.truth.arrays()
    done = len(truth["timer"])
    if sent != done * size or unit.records_skipped:
        raise AssertionError(f"capture out of step: {sent} bytes for {done} records")
    return Capture(
        rx_ns=np.array([round(t * 1e9) for t, _ in reads], np.int64) + WALL_NS,
        data=[d for _, d in reads], code=code, truth=truth, config=config, usb=usb)
