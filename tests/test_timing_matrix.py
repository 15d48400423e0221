"""Time at the rates, links and crystals a GX3 runs at, against the emulator's truth.

Units at 100 Hz to 1 kHz (at the baud rates the manual's Table 5 pairs with them) behind
a USB-serial adapter that hands the host every byte at each 1 ms frame, and on their own
USB port, which hands over whole records at the first frame after them; crystals a few
to tens of ppm from the host's. Each capture is timed as ``gx3 replay`` times it (live)
and as ``gx3 export`` re-estimates it from what the samples carry (offline, with the read
that ended inside each record or where it begins). Where the reads hold the information
(a frame inside records, or records crossing a frame boundary) the instants are within
0.1 ms of the truth, and units agree whatever their link and crystal; where they do not
(a unit whose records fall between the frames, in step with them), the uncertainty each
instant comes with says so, and holds the truth.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pytest

from bridge.ingest.replay import frame_reads
from bridge.protocol.framer import Framer
from bridge.sim.capture import (
    USB_BAUD,
    WALL_NS,
    SyntheticCapture,
    streaming_config,
    synthesize,
)
from bridge.sim.motion import Motion, MotionConfig
from bridge.sim.unit import SimUnit, UnitConfig
from bridge.sim.usb import AdapterDelivery, UartDelivery, UsbDelivery
from bridge.timing import Estimate, Settings, StreamTiming
from bridge.timing.links import infer_transport

CODE = 0xC2
WARM_NS = 5_000_000_000
BAUDS = {100: 115_200, 200: 230_400, 500: 460_800, 1000: 921_600}


@dataclass(frozen=True)
class Unit:
    rate: int
    link: str  # "adapter" or "usb"
    ppm: float
    phase_s: float  # where the host's 1 ms frames fall
    seconds: float = 60.0

    @property
    def settings(self) -> Settings:
        if self.link == "usb":
            return Settings(CODE, 1000 // self.rate, 15, USB_BAUD, "usb")
        return Settings(CODE, 1000 // self.rate, 15, BAUDS[self.rate], "usb-serial",
                        latency_timer_ms=1)


@dataclass(frozen=True)
class Timed:
    capture: SyntheticCapture
    live: np.ndarray
    offline: Estimate

    def errors(self, times: np.ndarray) -> np.ndarray:
        """time_ns less the instant the values describe, from 5 s on."""
        truth = self.capture.truth["value_ns"]
        return np.asarray((times - truth)[truth >= truth[0] + WARM_NS])


@cache
def timed(unit: Unit) -> Timed:
    """The unit's capture timed live, as replay does, and offline, as export does."""
    baud = USB_BAUD if unit.link == "usb" else BAUDS[unit.rate]
    config = streaming_config(UnitConfig(clock_ppm=unit.ppm, clock_seed=3), code=CODE,
                              decimation=1000 // unit.rate, baud=baud)
    delivery = UsbDelivery(frame_phase_s=unit.phase_s, os_latency_mean_s=0.0002, seed=5) \
        if unit.link == "usb" else AdapterDelivery(
            latency_timer_s=0.001, frame_phase_s=unit.phase_s, os_latency_mean_s=0.0002, seed=5)
    capture = synthesize(config, delivery, unit.seconds)
    stream = StreamTiming()
    stream.configure(unit.settings, True)
    live, ticks, rx, part, lead = [], [], [], [], []
    for found in frame_reads(Framer([CODE]), capture.rx_ns, capture.data):
        for batch in found:
            out = stream.process(batch)
            live.append(out.time_ns)
            ticks.append(out.ticks)
            rx.append(out.batch.rx_ns)
            part.append(out.part[0])
            lead.append(out.part[1])
    # the partial reads as the archive's samples carry them
    offline = unit.settings.offline_clock().estimate(
        np.concatenate(ticks), np.concatenate(rx), np.concatenate(part), np.concatenate(lead))
    return Timed(capture, np.concatenate(live), offline)


#: Units whose reads pin their instants within the capture: a frame lands inside
#: records (an adapter), or records cross frame boundaries (their own USB port).
PINNED = [
    Unit(100, "adapter", -55.0, 0.00021), Unit(200, "adapter", 12.0, 0.00063),
    Unit(500, "adapter", -3.0, 0.0005), Unit(1000, "adapter", 40.0, 0.00037),
    Unit(100, "usb", 40.0, 0.00077), Unit(500, "usb", -55.0, 0.0001),
    Unit(1000, "usb", 40.0, 0.0009),
]


@pytest.mark.parametrize("unit", PINNED, ids=lambda u: f"{u.rate}Hz-{u.link}-{u.ppm:+g}ppm")
def test_exported_time_is_within_a_tenth_of_a_millisecond(unit: Unit) -> None:
    t = timed(unit)
    offline = t.errors(t.offline.time_ns)
    assert np.percentile(np.abs(offline), 99) < 100_000, np.percentile(np.abs(offline), 99)
    # and within the uncertainty it comes with
    doubt = t.errors(t.offline.uncertainty_ns + t.capture.truth["value_ns"])
    assert np.mean(np.abs(offline) <= doubt + 5_000) > 0.999


@pytest.mark.parametrize("unit", PINNED, ids=lambda u: f"{u.rate}Hz-{u.link}-{u.ppm:+g}ppm")
def test_live_time_is_within_a_fifth_once_the_reads_have_pinned_it(unit: Unit) -> None:
    """Live, a unit's own USB port pins the line only once records have crossed two frame
    boundaries (the first alone leaves the rate open): from then on within 0.2 ms."""
    t = timed(unit)
    live = t.errors(t.live)
    pinned = np.flatnonzero(np.abs(t.errors(t.offline.time_ns)) < 50_000)
    assert len(pinned)
    settled = live[int(len(live) * 0.6):]  # the last 40 % of the capture: past two crossings
    assert np.percentile(np.abs(settled), 99) < 200_000, np.percentile(np.abs(settled), 99)


def test_units_agree_whatever_their_rate_link_and_crystal() -> None:
    """The same processing delay on every unit: their exported instants share one bias."""
    biases = [float(np.mean(timed(u).errors(timed(u).offline.time_ns))) for u in PINNED]
    assert max(biases) - min(biases) < 100_000, biases
    assert max(map(abs, biases)) < 50_000, biases


def test_a_unit_in_step_between_the_frames_says_how_unsure_it_is() -> None:
    """1 kHz behind an adapter at -3 ppm, the host's frames falling between its records
    for the whole capture: nothing tells where in the gap they are, and the instants
    say so (uncertainty about half the gap), the truth inside."""
    unit = Unit(1000, "adapter", -3.0, 0.0008, seconds=30.0)
    t = timed(unit)
    err = t.errors(t.offline.time_ns)
    doubt = t.errors(t.offline.uncertainty_ns + t.capture.truth["value_ns"])
    assert np.median(doubt) > 250_000
    assert np.mean(np.abs(err) <= doubt + 5_000) > 0.999


@pytest.mark.parametrize("unit", [Unit(200, "adapter", 12.0, 0.00063),
                                  Unit(1000, "adapter", 40.0, 0.00037),
                                  Unit(500, "adapter", -3.0, 0.0005),
                                  Unit(1000, "usb", 40.0, 0.0009)],
                         ids=["200Hz-adapter", "1kHz-adapter", "crawling-adapter", "1kHz-usb"])
def test_the_link_and_its_baud_rate_are_told_from_the_reads(unit: Unit) -> None:
    """An adapter's reads end inside records, which the unit's own port never gives, and
    hold every byte the line carried by their frame, at the adapter's baud rate. Where
    the unit crawls against the frames (-3 ppm: its records split at much the same
    byte for the whole minute) the split moves with the rate and the byte time alike,
    and no baud rate is claimed."""
    capture = timed(unit).capture
    found = infer_transport(capture.rx_ns, capture.data, CODE)
    s = unit.settings
    assert found.transport == s.transport, found.describe()
    if s.transport == "usb-serial":
        assert found.baud == (None if abs(unit.ppm) < 5 else s.baud), found.describe()


@pytest.mark.parametrize("code", [0xC3, 0xD3])
def test_delta_records_are_timed_at_the_middle_of_their_period(code: int) -> None:
    """DeltaAngle and DeltaVelocity integrate over the output period (the manual): their
    values describe its middle, half a period before an instantaneous record's. time_ns
    is that instant; the integral over the period, divided by it, is the rate there, and
    not at the period's end."""
    period = 0.01
    config = streaming_config(UnitConfig(clock_ppm=25.0, motion=MotionConfig(seed=4)),
                              code=code, decimation=10, baud=115_200)
    capture = synthesize(config, UartDelivery(seed=2), 30.0)
    stream = StreamTiming()
    stream.configure(Settings(code, 10, 15, 115_200, "uart"), True)
    timed = [stream.process(b) for found in frame_reads(Framer([code]), capture.rx_ns,
                                                        capture.data) for b in found]
    time_ns = np.concatenate([t.time_ns for t in timed])
    delta = np.concatenate([t.batch["delta_ang"] for t in timed]).astype(np.float64)
    truth = capture.truth["value_ns"]
    late = truth >= truth[0] + WARM_NS
    assert np.percentile(np.abs(time_ns - truth)[late], 99) < 30_000
    unit = SimUnit(config, now=0.0, wall_ns=WALL_NS)  # its clock, to map time_ns to it
    device = unit.device_time((time_ns[late] - WALL_NS) / 1e9)
    motion = Motion(config.motion)

    def off(shift_s: float) -> float:
        rate = motion.sample(device + shift_s, period, only=["ang_rate"])["ang_rate"]
        return float(np.sqrt(np.mean((delta[late] / period - rate) ** 2)))

    assert off(0.0) < 0.1 * off(period / 2)
