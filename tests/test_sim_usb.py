"""The USB delivery model and the drifting unit clock the timing tests stand on."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.clock import UnitClock
from bridge.sim.unit import SimUnit, UnitConfig
from bridge.sim.usb import UsbDelivery, UsbLink


def test_clock_inverse_is_exact_and_wander_stays_in_its_band() -> None:
    clock = UnitClock(12.0, ppm=40.0, wander_ppm=3.0, wander_period_s=120.0, seed=7)
    host = np.linspace(12.0, 3612.0, 20001)
    assert np.abs(clock.host(clock.device(host)) - host).max() < 1e-9
    assert clock.host(float(clock.device(500.0))) == pytest.approx(500.0, abs=1e-9)
    rate = clock.rate_ppm(host)
    assert 37.0 <= rate.min() < 39.0 and 41.0 < rate.max() <= 43.0
    assert np.all(np.diff(clock.device(host)) > 0)


def test_unit_without_wander_keeps_the_linear_clock_bit_for_bit() -> None:
    unit = SimUnit(UnitConfig(clock_ppm=-37.5), now=3.25, wall_ns=0)
    for t in (3.25, 10.0, 12345.678):
        assert unit.device_time(t) == (t - 3.25) * (1.0 - 37.5e-6)
        assert unit.host_time(unit.device_time(t)) == 3.25 + (t - 3.25) * (1.0 - 37.5e-6) / (
            1.0 - 37.5e-6)


def test_reads_never_come_before_the_frame_that_carried_the_bytes() -> None:
    usb = UsbDelivery(os_latency_mean_s=0.0004, stall_every_s=0.5, seed=3)
    link = UsbLink(usb)
    pushed = []
    reads = []
    for k in range(1, 5000):
        t = k * 0.00037
        link.push(bytes([k % 256]), t)
        pushed.append((t, k % 256))
        reads += link.reads(t)
    reads += link.reads(10.0)
    assert b"".join(d for _, d in reads) == bytes(b for _, b in pushed)
    times = np.array([t for t, _ in reads])
    assert np.all(np.diff(times) > 0)
    done = 0
    for t, data in reads:  # every byte was finished by the last frame boundary before t
        finished = pushed[done + len(data) - 1][0]
        assert link.frame_at(finished) <= t
        done += len(data)
    assert link.stalls > 0
    gaps = np.diff(times)
    assert gaps.max() >= usb.stall_min_s  # a stall held reads back ...
    assert max(len(d) for _, d in reads) > 10  # ... and delivered a burst


def test_capture_is_deterministic_and_matches_its_truth() -> None:
    config = streaming_config(UnitConfig(clock_ppm=25.0, clock_wander_ppm=2.0))
    usb = UsbDelivery(stall_every_s=0.5, seed=11)
    a, b = synthesize(config, usb, 6.0), synthesize(config, usb, 6.0)
    assert np.array_equal(a.rx_ns, b.rx_ns) and a.data == b.data
    timer, rx = a.records()
    assert np.array_equal(timer, a.truth["timer"]) and len(timer) > 550
    late = rx - a.truth["time_ns"]
    assert late.min() > 0  # USB delivers late, never early
    assert late.max() > 5_000_000  # and a stall delivers a burst late
