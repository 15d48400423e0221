"""The delivery models (native USB, USB-serial adapter, UART) and the drifting unit
clock the timing tests stand on."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.device.link import ADAPTER_PACKET_BYTES
from bridge.protocol.table import REPLIES
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.clock import UnitClock
from bridge.sim.unit import SimUnit, UnitConfig
from bridge.sim.usb import (
    AdapterDelivery,
    AdapterLink,
    HostDelivery,
    HostDriver,
    UartDelivery,
    UartLink,
    UsbDelivery,
    UsbLink,
    link_for,
)


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



def _stream(link: HostDriver, count: int, byte_s: float, seed: int
            ) -> tuple[np.ndarray, list[int], list[tuple[float, bytes]]]:
    """Push ``count`` bytes as records of random size and spacing, reading as time goes
    on, as a transport does: each byte's arrival (when it finished crossing the line),
    where each record ends in the stream, and every read."""
    rng = np.random.default_rng(seed)
    arrivals: list[float] = []
    ends: list[int] = []
    reads: list[tuple[float, bytes]] = []
    t = 0.01
    while len(arrivals) < count:
        start, size = len(arrivals), int(rng.integers(5, 120))
        t += float(rng.uniform(0.0, 0.012))
        arrivals += [t + (i + 1) * byte_s for i in range(size)]
        t = arrivals[-1]
        ends.append(len(arrivals))
        link.push(bytes(k % 251 for k in range(start, len(arrivals))), t, byte_s)
        reads += link.reads(t)
    reads += link.reads(t + 1.0)
    assert b"".join(d for _, d in reads) == bytes(k % 251 for k in range(len(arrivals)))
    return np.array(arrivals), ends, reads


@pytest.mark.parametrize(("timer_ms", "baud"), [(1, 921600), (16, 115200)])
def test_adapter_obeys_its_packet_and_latency_timer_rules(timer_ms: int, baud: int) -> None:
    """Without OS latency each read is one frame's packets: full 62-byte packets, or
    everything held once the timer since the last packet ran out; and no poll leaves
    a full packet, or bytes behind an expired timer, in the adapter."""
    usb = AdapterDelivery(latency_timer_s=timer_ms / 1000, frame_phase_s=0.00037,
                          os_latency_mean_s=0.0, stall_every_s=0.0)
    link = AdapterLink(usb)
    arrived, _, reads = _stream(link, 20000, 10 / baud, seed=1)
    sent_at = {link.frame_index(t): len(d) for t, d in reads}
    assert len(sent_at) == len(reads)
    assert all(abs(link.frame_time(link.frame_index(t)) - t) < 1e-12 for t, _ in reads)
    sent, last, full, expired = 0, -(10**9), 0, 0
    for k in range(min(sent_at), max(sent_at) + 1):
        held = int(np.searchsorted(arrived, link.frame_time(k), "right")) - sent
        timer_out = k - last >= timer_ms
        n = sent_at.get(k, 0)
        if not n:
            assert held < ADAPTER_PACKET_BYTES and not (timer_out and held)
            continue
        if timer_out:
            assert n == held
            expired += 1
        else:
            assert n % ADAPTER_PACKET_BYTES == 0 and 0 <= held - n < ADAPTER_PACKET_BYTES
            full += 1
        sent, last = sent + n, k
    assert expired > 10 and link.packets >= full + expired
    assert full > 10 or timer_ms == 1  # a 1 ms timer has always run out by the next frame
    assert max(sent_at.values()) > ADAPTER_PACKET_BYTES  # several packets in one frame


@pytest.mark.parametrize("delivery", [
    AdapterDelivery(latency_timer_s=0.001, frame_phase_s=0.0002, stall_every_s=0.3, seed=4),
    AdapterDelivery(latency_timer_s=0.016, frame_phase_s=0.0009, stall_every_s=0.3, seed=5),
    UartDelivery(stall_every_s=0.3, seed=6)], ids=["adapter-1ms", "adapter-16ms", "uart"])
def test_serial_reads_come_late_and_often_end_mid_record(delivery: HostDelivery) -> None:
    link = link_for(delivery)
    arrived, ends, reads = _stream(link, 30000, 10 / 115200, seed=2)
    times = np.array([t for t, _ in reads])
    assert np.all(np.diff(times) > 0) and all(reads[i][1] for i in range(len(reads)))
    through = np.cumsum([len(d) for _, d in reads])
    assert np.all(arrived[through - 1] <= times)  # nothing read before it crossed the line
    if isinstance(link, UartLink):  # a read takes every byte that had crossed by then
        assert np.array_equal(through, np.searchsorted(arrived, times, "right"))
    mid = np.isin(through, ends, invert=True).mean()
    assert mid > 0.3
    assert link.stalls > 0 and np.diff(times).max() >= delivery.stall_min_s


@pytest.mark.parametrize("delivery", [
    AdapterDelivery(latency_timer_s=0.001, frame_phase_s=0.00063, seed=7),
    AdapterDelivery(latency_timer_s=0.016, frame_phase_s=0.00011, seed=8),
    UartDelivery(seed=9)], ids=["adapter-1ms", "adapter-16ms", "uart"])
def test_capture_over_a_serial_link_reassembles_and_matches_its_truth(
        delivery: HostDelivery) -> None:
    config = streaming_config(UnitConfig(clock_ppm=-30.0), code=0xCC, baud=115200)
    a, b = synthesize(config, delivery, 8.0), synthesize(config, delivery, 8.0)
    assert np.array_equal(a.rx_ns, b.rx_ns) and a.data == b.data
    timer, rx = a.records()
    assert np.array_equal(timer, a.truth["timer"]) and len(timer) > 750
    line_ns = REPLIES[0xCC].length * 10 / 115200 * 1e9
    assert (rx - a.truth["time_ns"]).min() >= line_ns - 1_000  # read after its last byte
    through = np.cumsum([len(d) for d in a.data])
    assert (through % REPLIES[0xCC].length != 0).mean() > 0.3


def test_capture_refuses_a_line_paced_for_another_link() -> None:
    with pytest.raises(ValueError, match="baud rate"):
        synthesize(streaming_config(UnitConfig()), UartDelivery(), 1.0)
    with pytest.raises(ValueError, match="USB speed"):
        synthesize(streaming_config(UnitConfig(), baud=115200), UsbDelivery(), 1.0)
    with pytest.raises(ValueError, match="do not fit"):
        synthesize(streaming_config(UnitConfig(), code=0xCC, decimation=1, baud=115200),
                   UartDelivery(), 1.0)


@pytest.mark.parametrize("rate", [100, 1000])
def test_the_units_own_port_hands_over_whole_records_at_the_next_frame(rate: int) -> None:
    """Each record's last byte goes out the processing delay and its transfer after its
    cycle; the host's driver gets the record whole at the first frame after that, and
    never a part of one."""
    config = streaming_config(UnitConfig(clock_ppm=-3.0), decimation=1000 // rate)
    usb = UsbDelivery(frame_phase_s=0.00061, os_latency_mean_s=0.0, stall_every_s=0.0)
    capture = synthesize(config, usb, 3.0)
    size = REPLIES[0xC2].length
    assert all(len(d) % size == 0 for d in capture.data), "a read ended inside a record"
    finished = capture.truth["time_ns"] + round(config.processing_delay_s * 1e9) + size * 1_000
    frame = 1_000_000
    phase = 610_000 + 1_763_000_000_000_000_000 % frame
    first_frame = finished + (phase - finished) % frame
    timer, rx = capture.records()
    assert np.array_equal(timer, capture.truth["timer"])
    np.testing.assert_array_equal(rx, first_frame)


def test_a_record_leaves_the_processing_delay_after_its_cycle() -> None:
    """On a UART each record's first byte crosses the line a fixed processing delay after
    the cycle that sampled it; a slower unit's firmware is later by its own."""
    size, byte_ns = REPLIES[0xC2].length, 10e9 / 115_200
    for delay_s in (0.0002, 0.0007):
        config = streaming_config(UnitConfig(processing_delay_s=delay_s), baud=115_200)
        capture = synthesize(config, UartDelivery(os_latency_mean_s=0.0, stall_every_s=0.0),
                             2.0)
        # with no latency the driver reads each byte as it has crossed the line
        begins = np.cumsum([0, *map(len, capture.data)])[:-1] % size == 0
        cycles = capture.truth["time_ns"]
        lead = capture.rx_ns[begins][: len(cycles)] - cycles
        assert len(lead) == len(cycles) > 150
        assert np.all(np.abs(lead - (delay_s * 1e9 + byte_ns)) < 2_000)
