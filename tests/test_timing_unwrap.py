"""Timer unwrapping: rollover, reset, gap and glitch, told apart."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.protocol.codec import checksum
from bridge.protocol.framer import Framer
from bridge.protocol.table import REPLIES
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from bridge.timing import Timeline, TimerUnwrapper, TimingEvent

PERIOD = 625  # decimation 10
RX0 = 1_700_000_000_000_000_000


def _stream(first: int, n: int, t0: int = RX0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` records one period apart from timer ``first`` (wrapping), received 1 ms late."""
    ticks = first + PERIOD * np.arange(n, dtype=np.int64)
    return (ticks % (1 << 32)).astype(np.uint32), t0 + (ticks - first) * 16_000 + 1_000_000


def _kinds(events: list[TimingEvent]) -> list[str]:
    return [e.kind for e in events]


def test_rollover_keeps_ticks_increasing_across_batches() -> None:
    timer, rx = _stream((1 << 32) - 3 * PERIOD, 8)
    u = TimerUnwrapper(PERIOD)
    a, b = u.update(timer[:2], rx[:2]), u.update(timer[2:], rx[2:])
    ticks = np.concatenate([a.ticks, b.ticks])
    assert np.all(np.diff(ticks) == PERIOD) and ticks[-1] > 1 << 32
    assert _kinds(a.events + b.events) == ["rollover"] and b.events[0].index == 1
    assert u.rollovers == 1 and u.dropped == 0 and a.valid.all() and b.valid.all()


def test_gap_counts_the_missing_samples_from_the_period() -> None:
    timer, rx = _stream(1000, 20)
    keep = np.r_[0:5, 9:20]  # records 5..8 never arrived
    out = TimerUnwrapper(PERIOD).update(timer[keep], rx[keep])
    assert out.dropped == 4 and _kinds(out.events) == ["gap"]
    assert out.events[0].index == 5 and out.events[0].count == 4
    assert np.array_equal(out.ticks, 1000 + PERIOD * keep)


def test_reset_is_a_new_epoch_not_a_rollover() -> None:
    before, rx1 = _stream(90_000_000, 10)
    after, rx2 = _stream(0, 10, t0=int(rx1[-1]) + 500_000_000)  # 0xFE: restarts near 0
    u = TimerUnwrapper(PERIOD)
    out = u.update(np.r_[before, after], np.r_[rx1, rx2])
    assert _kinds(out.events) == ["reset"] and u.rollovers == 0 and u.resets == 1
    # Unannounced, the first record of the new epoch cannot be told from a glitch.
    assert out.valid.tolist() == [True] * 10 + [False] + [True] * 9
    good = out.ticks[out.valid]
    assert np.all(np.diff(good) > 0)
    assert np.all(np.diff(out.ticks[11:]) == PERIOD)


def test_announced_reset_loses_nothing() -> None:
    before, rx1 = _stream(90_000_000, 10)
    after, rx2 = _stream(12_345, 10, t0=int(rx1[-1]) + 50_000_000)  # 0xD7 timer set
    u = TimerUnwrapper(PERIOD)
    u.update(before, rx1)
    u.expect_discontinuity()
    out = u.update(after, rx2)
    assert out.valid.all() and _kinds(out.events) == ["reset"]
    assert out.ticks[0] > 90_000_000 + 9 * PERIOD and np.all(np.diff(out.ticks) == PERIOD)


def test_every_single_bit_flip_of_the_timer_is_refused() -> None:
    timer, rx = _stream(5_000_000, 3)
    for bit in range(32):
        bad = timer.copy()
        bad[1] ^= np.uint32(1 << bit)
        out = TimerUnwrapper(PERIOD).update(bad, rx)
        assert out.valid.tolist() == [True, False, True], bit
        assert _kinds(out.events) == ["glitch"] and out.events[0].index == 1


def _compensating_flip(record: bytes, timer_byte: int) -> bytes:
    """Flip a clear bit in a timer byte and the same bit, set, in another byte:
    the additive checksum cannot see it."""
    data = bytearray(record)
    for bit in range(8):
        if not data[timer_byte] >> bit & 1:
            for other in range(1, timer_byte - 4):
                if data[other] >> bit & 1:
                    data[timer_byte] |= 1 << bit
                    data[other] &= ~(1 << bit) & 0xFF
                    return bytes(data)
    raise AssertionError("no compensating pair in this record")


def test_corrupt_timer_passing_the_checksum_is_flagged_and_dropped() -> None:
    capture = synthesize(streaming_config(UnitConfig(), code=0xC2), UsbDelivery(seed=5), 1.0)
    size = REPLIES[0xC2].length
    stream = b"".join(capture.data)
    n = len(stream) // size
    records = [stream[i * size : (i + 1) * size] for i in range(n)]
    records[40] = _compensating_flip(records[40], size - 5)  # timer's high-middle byte
    assert checksum(records[40][:-2]) == int.from_bytes(records[40][-2:], "big")
    batches = Framer(expect=[0xC2]).feed(b"".join(records))
    timer = np.concatenate([b["timer"] for b in batches])
    assert len(timer) == n and timer[40] != capture.truth["timer"][40]  # the framer took it
    rx = capture.truth["time_ns"][:n] + 2_000_000
    out = TimerUnwrapper(PERIOD).update(timer, rx)
    assert out.valid.sum() == n - 1 and not out.valid[40]
    assert _kinds(out.events) == ["glitch"] and out.dropped == 0
    assert np.array_equal(out.ticks[out.valid], capture.truth["timer"][:n][out.valid])


def test_without_a_period_host_time_still_refuses_a_wild_jump() -> None:
    timer, rx = _stream(5_000_000, 3)
    timer[1] ^= np.uint32(1 << 28)
    out = TimerUnwrapper(None).update(timer, rx)
    assert out.valid.tolist() == [True, False, True]


KHZ = 62.5  # ticks per output period at 1 kHz (decimation 1)


def _backlog(stall_s: float, buffered_s: float, reset_to: int | None = None,
             n_s: float = 12.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 1 kHz stream read by a host that stalls at 5 s for ``stall_s``: the port's buffer
    keeps the first ``buffered_s`` of records, the rest of the stall is lost, and the
    backlog is read at once on waking. With ``reset_to`` the unit's timer restarts at
    that value where the records start to be lost. Returns timer, rx_ns, the cycle of
    each record and each record's sample instant."""
    cycles = np.arange(int(n_s * 1000), dtype=np.int64)
    ticks = (cycles * 125 + 1) >> 1  # 62.5 a cycle, rounded half up as the unit does
    sampled = RX0 + cycles * 1_000_000
    rx = sampled + 200_000
    stall, wake = 5_000, 5_000 + int(stall_s * 1000)
    lost = (cycles >= stall + int(buffered_s * 1000)) & (cycles < wake)
    rx[(cycles >= stall) & (cycles < wake + 3)] = sampled[wake] + 3_000_000  # all at once
    if reset_to is not None:
        start = stall + int(buffered_s * 1000)
        ticks[start:] = reset_to + ((cycles[start:] - start) * 125 + 1 >> 1)
    keep = ~lost
    timer = (ticks % (1 << 32)).astype(np.uint32)
    return timer[keep], rx[keep], cycles[keep], sampled[keep]


@pytest.mark.parametrize("stall_s", [1.0, 1.5, 3.0])
def test_a_backlog_after_a_host_stall_is_a_gap_not_a_reset(stall_s: float) -> None:
    timer, rx, cycles, sampled = _backlog(stall_s, buffered_s=0.4)
    out = Timeline(KHZ, floor_ns=0).update(timer, rx)
    missing = int(np.diff(cycles).max()) - 1
    assert missing == round((stall_s - 0.4) * 1000)
    assert _kinds(out.events) == ["gap"] and out.events[0].count == missing
    assert out.dropped == missing and out.valid.all()
    assert np.array_equal(out.ticks, (cycles * 125 + 1) >> 1), "ticks ran on through the stall"
    after = cycles >= 5_000 + stall_s * 1000
    error = np.abs(out.time_ns - sampled)[after]
    assert error.max() < 1_000_000, f"time_ns off by {error.max() / 1e6:.1f} ms after the stall"


@pytest.mark.parametrize("cut", [1, 5_399, 5_400, 5_401, 5_403, 7_000])
def test_a_judged_backlog_does_not_depend_on_how_records_are_split(cut: int) -> None:
    timer, rx, _, _ = _backlog(2.0, buffered_s=0.4)
    whole = Timeline(KHZ).update(timer, rx)
    timeline = Timeline(KHZ)
    parts = [timeline.update(timer[a:b], rx[a:b])
             for a, b in ((0, cut), (cut, cut + 3), (cut + 3, len(timer)))]
    assert np.array_equal(whole.ticks, np.concatenate([p.ticks for p in parts]))
    assert np.array_equal(whole.time_ns, np.concatenate([p.time_ns for p in parts]))
    assert [(e.kind, e.count) for p in parts for e in p.events] == [("gap", 1600)]


@pytest.mark.parametrize("reset_to", [0, 12_345, 5_400 * 63 + 200_000])
def test_a_reset_in_a_backlog_is_still_a_reset(reset_to: int) -> None:
    """0xFE or a power cycle restarts the timer near 0, 0xD7 at the value set: not where
    the clock model says a timer that ran on would be."""
    timer, rx, _, _ = _backlog(2.0, buffered_s=0.4, reset_to=reset_to)
    out = Timeline(KHZ).update(timer, rx)
    assert _kinds(out.events) == ["reset"] and out.dropped == 0
    assert np.all(np.diff(out.ticks[out.valid]) > 0)


@pytest.mark.parametrize("reset_to", [None, 0])
def test_a_reconnect_after_a_backlog_is_judged_by_the_clock_model(
        reset_to: int | None) -> None:
    """The host woke from a stall, read what the port had kept (the last record it will
    get, seconds late) and lost the link; the unit came back a second later. Its timer
    ran on: a gap of exactly the records lost; or it restarted: a reset."""
    timer, rx, cycles, sampled = _backlog(2.0, buffered_s=0.4, reset_to=reset_to)
    back = int(np.searchsorted(cycles, 7_000))
    rx[back:] = sampled[back:] + 200_000  # the link was down: nothing came with the backlog
    timeline = Timeline(KHZ)
    before = timeline.update(timer[:back], rx[:back])
    timeline.expect_discontinuity()
    after = timeline.update(timer[back:], rx[back:])
    assert not before.events
    if reset_to is None:
        assert [(e.kind, e.count) for e in after.events] == [("gap", 1600)]
        assert np.array_equal(after.ticks, (cycles[back:] * 125 + 1) >> 1)
        assert np.abs(after.time_ns - sampled[back:]).max() < 1_000_000
    else:
        assert _kinds(after.events) == ["reset"] and after.valid.all()
