"""Timing over every link, as the bridge and ``gx3 replay`` time a capture: reads that
end inside records, USB-serial adapters, and the offline pass against the live one."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from bridge.ingest.replay import frame_reads
from bridge.protocol.codec import Batch
from bridge.protocol.framer import Framer
from bridge.sim.capture import USB_BAUD, SyntheticCapture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery
from bridge.timing.stream import Settings, StreamTiming

CODE = 0xC2
BAUD = 115_200
WARM_NS = 30_000_000_000


def _delivery(transport: str, phase_s: float, latency_s: float, seed: int,
              timer_s: float = 0.001) -> HostDelivery:
    if transport == "usb":
        return UsbDelivery(frame_phase_s=phase_s, os_latency_mean_s=latency_s, seed=seed)
    if transport == "uart":
        return UartDelivery(os_latency_mean_s=latency_s, seed=seed)
    return AdapterDelivery(frame_phase_s=phase_s, os_latency_mean_s=latency_s, seed=seed,
                           latency_timer_s=timer_s)


@cache
def _capture(transport: str, ppm: float, wander: float, phase_s: float, seconds: float,
             timer_s: float = 0.001, seed: int = 1) -> SyntheticCapture:
    baud = USB_BAUD if transport == "usb" else BAUD
    config = streaming_config(UnitConfig(clock_ppm=ppm, clock_wander_ppm=wander,
                                         clock_wander_period_s=200.0, clock_seed=seed),
                              code=CODE, baud=baud)
    return synthesize(config, _delivery(transport, phase_s, 0.0008, seed, timer_s), seconds)


def _settings(capture: SyntheticCapture) -> Settings:
    c = capture.config.stored
    return Settings(CODE, c.sampling.decimation, c.sampling.filter_width, c.baud,
                    capture.delivery.transport)


def _replayed(capture: SyntheticCapture) -> tuple[list[Batch], np.ndarray, np.ndarray]:
    """The capture as ``gx3 replay`` reads it: batches, their ticks and live instants."""
    stream = StreamTiming()
    stream.configure(_settings(capture), True)
    batches = [b for found in frame_reads(Framer([CODE]), capture.rx_ns, capture.data)
               for b in found]
    timed = [stream.process(b) for b in batches]
    return ([t.batch for t in timed], np.concatenate([t.ticks for t in timed]),
            np.concatenate([t.time_ns for t in timed]))


def _offline(capture: SyntheticCapture, batches: list[Batch], ticks: np.ndarray,
             parts: bool = True) -> np.ndarray:
    s = _settings(capture)
    whole = Batch.concatenate(batches)
    part_ns, part_bytes = whole.partial()
    clock = s.offline_clock()
    if not parts:
        return clock.smooth(ticks, whole.rx_ns)
    return clock.smooth(ticks, whole.rx_ns, part_ns, s.part_lead_ns(part_bytes))


def _errors(capture: SyntheticCapture, time_ns: np.ndarray) -> np.ndarray:
    truth = capture.truth["value_ns"]
    late = truth >= truth[0] + WARM_NS
    return np.asarray(np.abs(time_ns - truth)[late])


def test_live_reads_give_replays_instants_with_partial_reads() -> None:
    """A live bridge on a USB-serial adapter, one read at a time (a read's record or two
    through ``process_few``, the others through ``process``), and the same reads cut in
    two at the same receive time, time every record as the bulk replay does."""
    capture = _capture("usb-serial", 30.0, 2.0, 0.0004, 40.0)
    batches, ticks, replayed = _replayed(capture)
    assert sum(b.part_ns is not None for b in batches)  # reads did end inside records
    for halves in (False, True):
        stream = StreamTiming()
        stream.configure(_settings(capture), True)
        framer = Framer([CODE])
        live_ticks, live = [], []
        for rx, data in zip(capture.rx_ns.tolist(), capture.data, strict=True):
            cut = len(data) // 2 if halves else 0
            for batch in framer.feed(data[:cut], rx) + framer.feed(data[cut:], rx):
                part_ns, part_bytes = batch.partial()
                few = None
                if len(batch) <= 2:
                    few = stream.process_few(batch["timer"].tolist(), batch.rx_ns.tolist(),
                                             part_ns.tolist(), part_bytes.tolist())
                if few is None:
                    timed = stream.process(batch)
                    live_ticks += timed.ticks.tolist()
                    live += timed.time_ns.tolist()
                else:
                    live_ticks += few.ticks
                    live += few.time_ns
        assert np.array_equal(np.array(live_ticks), ticks)
        assert np.array_equal(np.array(live), replayed)


@pytest.mark.parametrize(("transport", "ppm"), [("usb-serial", 1.0), ("uart", -60.0)])
def test_partial_reads_pin_each_record_to_a_byte(transport: str, ppm: float) -> None:
    """Over a serial line a read that ends inside a record bounds its start by the bytes
    it held; behind an adapter's frames that pins even a unit whose phase crawls
    against the frame clock (the frames alone leave it half a frame in doubt)."""
    capture = _capture(transport, ppm, 0.0, 0.00093, 120.0)
    batches, ticks, live = _replayed(capture)
    whole = Batch.concatenate(batches)
    s = _settings(capture)
    bare = StreamTiming()
    bare.configure(s, True)
    assert bare.timeline is not None
    without = bare.timeline.update(whole["timer"], whole.rx_ns).time_ns
    live_p99 = np.percentile(_errors(capture, live), 99)
    assert live_p99 < 60_000, live_p99
    assert live_p99 < 0.5 * np.percentile(_errors(capture, without), 99)
    offline = _errors(capture, _offline(capture, batches, ticks))
    assert np.percentile(offline, 99) < 20_000, np.percentile(offline, 99)
    assert np.percentile(offline, 99) < 0.5 * np.percentile(
        _errors(capture, _offline(capture, batches, ticks, parts=False)), 99)


#: link, clock ppm, wander ppm, frame phase s: slow beaters on every framed link, units
#: that sweep the frame with wander, a plain UART
UNITS = [
    ("usb", 1.0, 0.0, 0.00093), ("usb", -2.0, 0.5, 0.00055), ("usb", 40.0, 3.0, 0.0002),
    ("usb-serial", 1.0, 0.0, 0.00093), ("usb-serial", -2.0, 0.5, 0.00055),
    ("uart", 25.0, 4.0, 0.0), ("uart", 1.0, 0.0, 0.0),
]


@pytest.mark.parametrize(("transport", "ppm", "wander", "phase"), UNITS)
def test_offline_is_never_worse_than_live(transport: str, ppm: float, wander: float,
                                          phase: float) -> None:
    """The offline pass sees both sides of every record: on no unit may its p99 or its
    largest error exceed the live estimate's (by more than 1 us, a sixteenth of the
    unit's timer tick: where neither knows more, a UART's envelope through windows
    centred on anchors 5 s apart and the live one through trailing windows differ by
    a fraction of a microsecond)."""
    capture = _capture(transport, ppm, wander, phase, 150.0, 0.016 if ppm < 2 else 0.001)
    batches, ticks, live = _replayed(capture)
    offline = _errors(capture, _offline(capture, batches, ticks))
    online = _errors(capture, live)
    assert np.percentile(offline, 99) <= np.percentile(online, 99) + 1_000
    assert offline.max() <= online.max() + 1_000
