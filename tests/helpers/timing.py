"""Emulated USB captures in virtual time, and the clock model's errors against their truth."""

from __future__ import annotations

from functools import cache

import numpy as np

from bridge.protocol.table import PROCESSING_DELAY_S, REPLIES
from bridge.sim.capture import SyntheticCapture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from bridge.timing import Timeline, record_delay_ns

FRAME_NS = 1_000_000
WARM_NS = 30_000_000_000
CODE = 0xC2
FLOOR_NS = REPLIES[CODE].length * 1_000  # the emulated USB moves 1 MB/s: 1 us a byte


@cache
def usb_capture(ppm: float, wander: float, seconds: float, phase_s: float,
                timer_start: int = 0) -> SyntheticCapture:
    """``seconds`` of 0xC2 records from a unit whose clock is ``ppm`` off (wandering by
    ``wander`` ppm), read over USB with its frame clock at ``phase_s`` (cached)."""
    config = streaming_config(UnitConfig(clock_ppm=ppm, clock_wander_ppm=wander,
                                         clock_wander_period_s=120.0, clock_seed=3,
                                         timer_start=timer_start), code=CODE)
    usb = UsbDelivery(frame_phase_s=phase_s, os_latency_mean_s=0.0003, stall_every_s=8.0,
                      seed=int(ppm * 10) % 97)
    return synthesize(config, usb, seconds)


def phase_for_crossing(ppm: float, first_s: float) -> float:
    """The USB frame phase (s) at which a 100 Hz unit's records first cross a frame
    boundary ``first_s`` into a capture, and then every 1 ms / ``ppm`` us a second.

    The unit's own port hands a record over at the first frame after its last byte: its
    cycle's instant, the processing delay and its transfer on; a fast unit's records come
    earlier against the frames by ``ppm`` microseconds a second.
    """
    done = PROCESSING_DELAY_S + FLOOR_NS / 1e9
    return (done - ppm * 1e-6 * first_s) % 0.001


def delay_ns(capture: SyntheticCapture) -> int:
    """From the instant ``capture``'s records describe to their first byte on the line."""
    return record_delay_ns(capture.config.stored.sampling.filter_width)


def late_errors(capture: SyntheticCapture, time_ns: np.ndarray) -> np.ndarray:
    """|estimate - the instant the values describe| after the warm-up."""
    truth = capture.truth["value_ns"]
    late = truth >= truth[0] + WARM_NS
    return np.asarray(np.abs(time_ns - truth)[late])


def make_timeline(capture: SyntheticCapture, frame_ns: int = FRAME_NS) -> Timeline:
    """The online clock's timeline for ``capture``'s unit and link."""
    return Timeline(625, delay_ns=delay_ns(capture), floor_ns=FLOOR_NS,
                    frame_ns=frame_ns)


def online_times(capture: SyntheticCapture, frame_ns: int = FRAME_NS) -> np.ndarray:
    """The online clock's time for each of ``capture``'s records, all valid."""
    timer, rx = capture.records()
    out = make_timeline(capture, frame_ns).update(timer, rx)
    assert out.valid.all()
    return out.time_ns
