"""Raw captures in virtual time: what a bridge would have read from one unit.

A unit streaming from power-up is run through a delivery model (native USB, a
USB-serial adapter or a UART: ``bridge.sim.usb``) for a given stretch of virtual
time. The result is what the bridge records (the bytes of each read and its host
receive time) next to the emulator's truth for every record, so the timing layer
can be scored against the real sample instants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.protocol.framer import Framer
from bridge.protocol.table import CALCULATION_CYCLE_S, REPLIES, Mode
from bridge.sim.state import Sampling
from bridge.sim.unit import SimUnit, UnitConfig
from bridge.sim.usb import HostDelivery, link_for

#: USB full speed moves about 1 MB/s of payload; the unit's line is paced at baud/10.
USB_BAUD = 10_000_000
WALL_NS = 1_763_000_000_000_000_000  # where virtual host time 0 sits on the wall clock


@dataclass
class SyntheticCapture:
    """Reads (receive time, bytes) and the truth of every record sent, oldest first.

    Attributes:
        rx_ns: Each read's receive time, host ns (int64).
        data: Each read's bytes.
        code: The record type streamed.
        truth: Per record sent, as ``TruthLog.arrays`` gives it.
        config: The unit, as it ran.
        delivery: The link: native USB, a USB-serial adapter or a UART.
    """

    rx_ns: np.ndarray  # int64, one per read
    data: list[bytes]
    code: int
    truth: dict[str, np.ndarray]  # timer, time_ns, value_ns when the emulator has it, ...
    config: UnitConfig
    delivery: HostDelivery  # native USB, a USB-serial adapter or a UART

    def write(self, path: Path, unit: str, prefix: str = "gx3") -> Path:
        """Write the reads as a bridge's raw capture (``--capture``), for ``gx3 replay``.

        With the metadata a bridge writes of the unit and its link, so that a replay
        times the records as that bridge would have.

        Args:
            path: The capture file to create.
            unit: The unit's name.
            prefix: The key prefix of its topic.

        Returns:
            ``path``.

        Raises:
            CaptureError: The file exists or cannot be written.
        """
        sampling, delivery = self.config.stored.sampling, self.delivery
        metadata = {"unit": unit, "record": f"0x{self.code:02X}",
                    "decimation": str(sampling.decimation),
                    "filter_width": str(sampling.filter_width),
                    "baud": str(self.config.stored.baud), "transport": delivery.transport}
        timer_s = getattr(delivery, "latency_timer_s", None)
        if timer_s is not None:
            metadata["latency_timer_ms"] = str(round(timer_s * 1000))
        writer = RawCaptureWriter(path, prefix, unit, metadata)
        try:
            for rx, data in zip(self.rx_ns.tolist(), self.data, strict=True):
                writer.write(data, rx)
        finally:
            writer.close()
        return path

    def records(self) -> tuple[np.ndarray, np.ndarray]:
        """Every record's timer and the receive time of the read that completed it.

        As the framer finds them in the reads: what the bridge feeds the timeline.

        Returns:
            (timers, uint32; receive times, int64 ns), one each per record.
        """
        framer = Framer(expect=[self.code])
        timers, rx = [], []
        for rx_ns, data in zip(self.rx_ns.tolist(), self.data, strict=True):
            for batch in framer.feed(data):
                timers.append(batch["timer"])
                rx.append(np.full(len(batch["timer"]), rx_ns, np.int64))
        return (np.concatenate(timers).astype(np.uint32) if timers else np.zeros(0, np.uint32),
                np.concatenate(rx) if rx else np.zeros(0, np.int64))


def streaming_config(config: UnitConfig, code: int = 0xC2, decimation: int = 10,
                     filter_width: int | None = None, baud: int = USB_BAUD) -> UnitConfig:
    """``config`` with a stored preset that streams ``code`` from power-up.

    Args:
        config: The unit.
        code: The record type to stream.
        decimation: Calculation cycles (1 ms) per record.
        filter_width: The filter's width; None: the stored one.
        baud: The pace of its line: USB speed (``USB_BAUD``) by default, a serial
            port's rate behind a UART or a USB-serial adapter.

    Returns:
        The config, its stored memory changed.
    """
    s = config.stored
    sampling = replace(s.sampling, decimation=decimation,
                       filter_width=s.sampling.filter_width if filter_width is None
                       else filter_width)
    stored = replace(s, mode_preset=int(Mode.CONTINUOUS), continuous_preset=code,
                     baud=baud, sampling=Sampling(**vars(sampling)))
    return replace(config, stored=stored)


def synthesize(config: UnitConfig, delivery: HostDelivery, seconds: float,
               start: float = 0.0) -> SyntheticCapture:
    """Run a unit that streams from power-up at host time ``start`` for ``seconds``.

    Each record is handed to the link whole, with the instant each byte finished
    crossing the unit's line (known from the record's cycle and the baud rate),
    before the host reads past its first byte; this keeps 10 minutes of 100 Hz
    output to a few seconds of CPU on every link.

    Args:
        config: A unit that streams from power-up (``streaming_config``).
        delivery: The link to the host.
        seconds: How long to run, virtual seconds.
        start: Host time of power-up, virtual seconds.

    Returns:
        What the host read, beside the truth of every record.

    Raises:
        ValueError: The unit does not stream from power-up, its pace does not suit the
            link, or its records do not fit its line.
    """
    code = config.stored.continuous_preset
    if config.stored.mode_preset != Mode.CONTINUOUS or code not in REPLIES:
        raise ValueError("synthesize needs a unit that streams from power-up: "
                         "build its config with streaming_config()")
    if (delivery.transport == "usb") != (config.stored.baud == USB_BAUD):
        raise ValueError(f"a {delivery.transport} link needs "
                         + ("the unit paced at USB speed: streaming_config() without baud"
                            if delivery.transport == "usb" else
                            "the unit's baud rate: streaming_config(..., baud=115200)"))
    period = config.stored.sampling.decimation * CALCULATION_CYCLE_S
    size = REPLIES[code].length
    byte_s = 10.0 / config.stored.baud
    n_records = int(seconds / period) + 2
    config = replace(config, truth_length=n_records + 16)
    unit = SimUnit(config, now=start, wall_ns=WALL_NS)
    link = link_for(delivery, start)
    reads: list[tuple[float, bytes]] = []
    end = start + seconds
    data, t = b"", start
    while not len(unit.truth) and t <= end:  # power-up: until the first record begins
        t += period / 2
        data += unit.poll(t)
    device0 = float(unit.truth.arrays()["device_s"][0]) if len(unit.truth) else math.inf
    done = 0
    # from a record's cycle to its last byte at the host's end of the link
    lead = config.processing_delay_s + size * byte_s + config.link_latency_s
    while (finished := float(unit.host_time(device0 + done * period)) + lead) <= end:
        data += unit.poll(finished)
        if len(data) != size:
            break
        link.push(data, finished, byte_s)
        reads += link.reads(finished)
        data, done = b"", done + 1
    reads += link.reads(end + 1.0)  # what was on its way when the capture stopped
    truth = {k: v[:done] for k, v in unit.truth.arrays().items()}
    if len(data) not in (0, size) or unit.records_skipped:
        raise ValueError(f"the unit's records do not fit its line: {size} bytes every "
                         f"{period * 1e3:g} ms at {config.stored.baud} baud")
    return SyntheticCapture(
        rx_ns=np.array([round(t * 1e9) for t, _ in reads], np.int64) + WALL_NS,
        data=[d for _, d in reads], code=code, truth=truth, config=config, delivery=delivery)
