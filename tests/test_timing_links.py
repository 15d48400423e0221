"""A capture's link inferred from its receive times alone, on captures synthesized
over every link the emulator models, with clocks beating fast and slowly against the
host's frames, both latency timers and a range of OS latencies."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery
from bridge.timing.links import crowding, infer_transport

USB_PACE = 10_000_000  # streaming_config's default: the line at USB speed


def _delivery(link: str, seed: int, latency_s: float) -> HostDelivery:
    host = UartDelivery(os_latency_mean_s=latency_s, stall_every_s=10.0, seed=seed)
    phase = (seed * 0.000377) % 0.001
    if link == "uart":
        return host
    if link == "usb":
        return UsbDelivery(frame_phase_s=phase, **vars(host))
    timer = 0.001 if link == "usb-serial-1" else 0.016
    return AdapterDelivery(latency_timer_s=timer, frame_phase_s=phase, **vars(host))


CASES = [(link, seed) for seed in (1, 2, 3)
         for link in ("usb", "uart", "usb-serial-1", "usb-serial-16")]


@pytest.mark.parametrize(("link", "seed"), CASES, ids=[f"{k}-seed{s}" for k, s in CASES])
def test_each_link_is_told_from_its_receive_times(link: str, seed: int) -> None:
    code = (0xC2, 0xCC, 0xC8)[seed - 1]
    ppm = (35.0, -60.0, 1.5)[seed - 1]  # seed 3 beats slowly against the frame clock
    latency = (0.0003, 0.0008, 0.0005)[seed - 1]
    config = streaming_config(UnitConfig(clock_ppm=ppm, clock_wander_ppm=1.0, clock_seed=seed),
                              code=code, baud=USB_PACE if link == "usb" else 115_200)
    capture = synthesize(config, _delivery(link, seed, latency), 60.0)
    found = infer_transport(capture.rx_ns, capture.data, code)
    transport, _, timer = link.partition("-serial-")
    want = ("usb-serial", int(timer)) if timer else (transport, None)
    assert (found.transport, found.latency_timer_ms) == want, found.describe()
    assert found.describe().startswith(f"transport {want[0]}") and "\n" not in found.describe()


@pytest.mark.parametrize("link", ["usb", "uart", "usb-serial-1", "usb-serial-16"])
def test_a_fast_stream_at_921600_baud_is_told_too(link: str) -> None:
    config = streaming_config(UnitConfig(clock_ppm=-90.0, clock_seed=9), code=0xCC,
                              decimation=1, baud=USB_PACE if link == "usb" else 921_600)
    capture = synthesize(config, _delivery(link, 9, 0.0004), 40.0)
    found = infer_transport(capture.rx_ns, capture.data, 0xCC)
    transport, _, timer = link.partition("-serial-")
    assert (found.transport, found.latency_timer_ms) == (
        ("usb-serial", int(timer)) if timer else (transport, None)), found.describe()


def test_a_uart_capture_shows_its_baud_rate() -> None:
    config = streaming_config(UnitConfig(clock_ppm=20.0), code=0xC2, baud=230_400)
    capture = synthesize(config, UartDelivery(seed=4), 30.0)
    assert "230400 baud" in infer_transport(capture.rx_ns, capture.data, 0xC2).evidence


def test_crowding_sees_a_frame_clock_and_not_times_spread_evenly() -> None:
    rng = np.random.default_rng(1)
    frames = rng.integers(0, 10**6, 20_000) * 1_000_000 + 370_000
    framed = frames + rng.exponential(800_000, len(frames)).astype(np.int64)
    spread = rng.integers(0, 10**12, 20_000)
    assert crowding(framed) > 0.09 and crowding(spread) < 0.03
    assert crowding(np.zeros(0, np.int64)) == 0.0


def test_a_capture_with_no_record_of_the_type_is_timed_as_a_serial_line() -> None:
    found = infer_transport(np.array([1, 2], np.int64), [b"\x00" * 40, b"\x01" * 3], 0xC2)
    assert (found.transport, found.latency_timer_ms) == ("uart", None)
