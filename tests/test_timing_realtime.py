"""Instants on the raw clock mapped onto a disciplined realtime clock, and its steps and
slews named: what a host running chrony, ntpd or PTP does to ``time_ns``.

Reads are made up here with both stamps (the raw clock and a realtime clock that the
test steps and slews), so the truth is known exactly: an instant's realtime is its
raw time plus the offset the made-up clock had at that instant.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.device import clock
from bridge.timing.realtime import (
    MAX_SLEW,
    SLEW_PPM,
    STEP_MIN_NS,
    ClockChange,
    RealtimeReads,
    RealtimeTrack,
)
from bridge.timing.stream import StreamTiming

BOOT = 5_000_000_000_000  # the raw clock: ns since boot
EPOCH = 1_795_000_000_000_000_000  # the realtime clock at BOOT


class MovedClock:
    """A realtime clock that runs ``ppm`` fast against the raw clock, with steps and slews
    at raw instants: ``offset(raw)`` is realtime less raw."""

    def __init__(self, ppm: float = 0.0) -> None:
        self.ppm = ppm
        self.steps: list[tuple[int, int]] = []
        self.slews: list[tuple[int, int, int]] = []  # at, amount, duration

    def step(self, at: int, by: int) -> MovedClock:
        self.steps.append((at, by))
        return self

    def slew(self, at: int, by: int, ppm: float) -> MovedClock:
        self.slews.append((at, by, round(abs(by) / (ppm * 1e-6))))
        return self

    def offset(self, raw: np.ndarray) -> np.ndarray:
        raw = np.asarray(raw, np.int64)
        out = EPOCH - BOOT + np.round((raw - BOOT) * self.ppm * 1e-6).astype(np.int64)
        for at, by in self.steps:
            out += np.where(raw >= at, by, 0)
        for at, by, duration in self.slews:
            out += np.round(by * np.clip((raw - at) / duration, 0, 1)).astype(np.int64)
        return out


def reads(seconds: float, every_ns: int, moved: MovedClock, seed: int = 0
          ) -> tuple[np.ndarray, np.ndarray]:
    """Raw and realtime stamps of reads about ``every_ns`` apart."""
    rng = np.random.default_rng(seed)
    gaps = rng.integers(every_ns // 2, every_ns * 3 // 2, int(seconds * 1e9 / every_ns))
    raw = BOOT + np.cumsum(gaps)
    return raw, raw + moved.offset(raw)


def live(raw: np.ndarray, real: np.ndarray, lag_ns: int, cuts: int = 1
         ) -> tuple[np.ndarray, np.ndarray, list[ClockChange]]:
    """As a bridge does: the reads fed ``cuts`` at a time, after each cut one instant per
    read mapped, ``lag_ns`` before the read (a record's sample instant before the read
    that completed it). The instants, their realtime, and the changes named."""
    track, changes, out = RealtimeTrack(), [], []
    for start in range(0, len(raw), cuts):
        until = raw[start : start + cuts]
        changes += track.add(until.tolist(), real[start : start + cuts].tolist())
        out += track.map((until - lag_ns).tolist(), until.tolist())
    return raw - lag_ns, np.array(out), changes


def fed(raw: np.ndarray, real: np.ndarray) -> tuple[RealtimeTrack, list[ClockChange]]:
    track = RealtimeTrack()
    return track, track.add(raw.tolist(), real.tolist())


def test_a_host_that_only_runs_at_its_disciplined_rate_is_followed_with_no_event() -> None:
    moved = MovedClock(ppm=37.0)
    raw, real = reads(30, 1_000_000, moved)
    t, mapped, changes = live(raw, real, 400_000)
    assert changes == []
    assert np.abs(mapped - (t + moved.offset(t)))[1:].max() <= 1
    assert fed(raw, real)[0].offset_ns == real[-1] - raw[-1]


@pytest.mark.parametrize("by", [50_000_000, -50_000_000])
def test_a_step_shows_where_it_happened_and_is_named_once(by: int) -> None:
    at = BOOT + 5_000_400_000
    moved = MovedClock(ppm=-12.0).step(at, by)
    raw, real = reads(10, 2_000_000, moved)
    t, mapped, changes = live(raw, real, 700_000, cuts=3)
    assert [c.kind for c in changes] == ["step"]
    step = changes[0]
    assert step.size_ns == pytest.approx(by, abs=1_000)
    assert abs(step.raw_ns - at) <= step.span_ns
    assert "stepped" in step.describe() and "leap" not in step.describe()
    error = (mapped - (t + moved.offset(t)))[1:]
    wrong = np.flatnonzero(np.abs(error) > 1_000) + 1
    # only an instant between the two reads around the step can take the wrong side
    assert len(wrong) <= 1
    if len(wrong):
        i = int(wrong[0])
        assert raw[raw <= at][-1] <= t[i] < raw[raw > at][0]


@pytest.mark.parametrize(("by", "ppm"), [(50_000_000, 83_333.0), (-50_000_000, 83_333.0),
                                         (10_000_000, 500.0)],
                         ids=["chrony +50 ms", "chrony -50 ms", "ntpd 500 ppm"])
def test_a_slew_is_followed_at_its_rate_and_named_once(by: int, ppm: float) -> None:
    at = BOOT + 3_000_000_000
    moved = MovedClock(ppm=5.0).slew(at, by, ppm)
    raw, real = reads(30 + abs(by) / ppm * 1e-3, 1_000_000, moved)
    t, mapped, changes = live(raw, real, 500_000)
    assert [c.kind for c in changes] == ["slew"], [c.describe() for c in changes]
    assert changes[0].size_ns == pytest.approx(by, rel=0.02)
    assert abs(changes[0].raw_ns - at) <= 300_000_000
    rate = changes[0].size_ns / changes[0].span_ns * 1e6
    assert abs(rate) == pytest.approx(ppm, rel=0.1)
    assert f"{rate:+,.0f} ppm" in changes[0].describe()
    error = np.abs(mapped - (t + moved.offset(t)))[1:]
    # linear between reads: exact, but between the two reads around each end of the slew
    assert np.percentile(error, 99) <= 2
    assert error.max() <= MAX_SLEW * 1_500_000 / 2


def test_a_leap_second_is_a_step_back_of_a_second_at_midnight() -> None:
    """As the kernel inserts one (chrony's default): 00:00:00 becomes 23:59:59 again."""
    day = 86_400_000_000_000
    raw, _ = reads(4, 1_000_000, MovedClock())
    at = int(raw[len(raw) // 2])
    midnight = (EPOCH // day + 1) * day
    real = raw + (midnight - at) + np.where(raw >= at, -1_000_000_000, 0)
    _, changes = fed(raw, real)
    assert len(changes) == 1 and changes[0].leap
    assert changes[0].size_ns == -1_000_000_000
    assert changes[0].describe().startswith("a leap second")
    _, others = fed(raw, real + 3_600_000_000_000)  # a second's step at another hour
    assert len(others) == 1 and not others[0].leap


def test_offsets_noisy_as_real_stamps_are_no_steps() -> None:
    """Stamp pairs a few µs apart (a preempted thread), and reads close together."""
    rng = np.random.default_rng(3)
    raw = BOOT + np.cumsum(rng.integers(20_000, 3_000_000, 20_000))
    real = raw + EPOCH - BOOT + rng.integers(-PAIR, PAIR, len(raw))
    _, changes = fed(raw, real)
    assert changes == []


PAIR = clock.PAIR_NS // 2


@st.composite
def disciplined_reads(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Reads of a host whose clock is stepped and slewed at random, with noisy stamps."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    moved = MovedClock(ppm=draw(st.floats(-200, 200)))
    span = 20_000_000_000
    for _ in range(draw(st.integers(0, 3))):
        moved.step(BOOT + int(rng.integers(0, span)),
                   int(rng.choice([-1, 1]) * rng.integers(STEP_MIN_NS * 2, 2_000_000_000)))
    for _ in range(draw(st.integers(0, 2))):
        moved.slew(BOOT + int(rng.integers(0, span)),
                   int(rng.choice([-1, 1]) * rng.integers(1_000, 60_000_000)),
                   float(rng.choice([300.0, 500.0, 83_333.0])))
    raw = BOOT + np.cumsum(rng.integers(10_000, 30_000_000, draw(st.integers(2, 3000))))
    real = raw + moved.offset(raw) + rng.integers(-PAIR, PAIR, len(raw))
    return raw, real


@settings(max_examples=150, deadline=None)
@given(disciplined_reads(), st.integers(1, 50), st.integers(0, 2**32 - 1))
def test_live_and_a_captures_reads_map_alike_however_the_reads_are_cut(
        reads_: tuple[np.ndarray, np.ndarray], cuts: int, seed: int) -> None:
    """``gx3 replay`` maps instants with a capture's reads all at once; the bridge did it
    read by read: the same instants, the same steps and slews named."""
    raw, real = reads_
    rng = np.random.default_rng(seed)
    track, live_changes = RealtimeTrack(), []
    instants: list[int] = []
    until: list[int] = []
    live: list[int] = []
    for start in range(0, len(raw), cuts):
        live_changes += track.add(raw[start : start + cuts].tolist(),
                                  real[start : start + cuts].tolist())
        done = raw[: start + cuts]
        u = rng.choice(done[-min(len(done), 5):], 4)  # records completed by recent reads
        t = u - rng.integers(-50_000_000, 50_000_000, 4)  # some ahead of their read
        instants += t.tolist()
        until += u.tolist()
        live += track.map(t.tolist(), u.tolist())
    capture = RealtimeReads(raw, real)
    assert capture.map(instants, until) == live
    assert capture.changes() == live_changes


def test_a_step_is_no_slower_than_any_slew() -> None:
    """The rule that tells a step from a slew, at its edges."""
    raw = np.array([BOOT, BOOT + 100_000, BOOT + 200_000])  # slewed at most 10 µs apart
    for change, step in ((STEP_MIN_NS + 1, True), (STEP_MIN_NS, False)):
        real = raw + EPOCH - BOOT + np.array([0, 0, change])
        assert bool(RealtimeReads(raw, real).changes()) == step
    fast = int(MAX_SLEW * 1_000_000_000) - 1  # just slower than any slew over a second
    raw = np.array([BOOT, BOOT + 1_000_000_000])
    assert RealtimeReads(raw, raw + np.array([0, fast])).changes() == []
    assert SLEW_PPM < 500  # ntpd's slews are named


def write_script(path: Path, **spec: object) -> None:
    path.write_text(json.dumps(spec))


def test_a_clock_script_steps_and_slews_this_processes_realtime_clock(tmp_path: Path) -> None:
    script = tmp_path / "clock.json"
    now = time.time_ns()
    write_script(script, changes=[{"at_ns": now - 10, "step_ns": 50_000_000},
                                  {"at_ns": now + 3_600_000_000_000, "step_ns": -1}],
                 sync={"synchronised": False, "estimated_error_ns": 7})
    try:
        clock.use_script(script)
        raw, real = clock.stamp()
        assert 49_000_000 < real - time.time_ns() <= 50_000_000
        assert abs(raw - time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW)) < 1_000_000_000
        assert 49_000_000 < clock.realtime_ns() - time.time_ns() <= 50_000_000
        sync = clock.host_sync()
        assert sync.known and not sync.synchronised and sync.estimated_error_ns == 7
        assert clock.moved([now]) == [now + 50_000_000]
        # a slew: half of it done halfway; the file read again once it changed
        write_script(script, changes=[{"at_ns": now, "slew_ns": 10_000_000, "ppm": 500}])
        os.utime(script, ns=(now + 1, now + 1))
        time.sleep(clock._RECHECK_S * 1.5)
        assert clock.moved([now + 10_000_000_000]) == [now + 10_000_000_000 + 5_000_000]
        assert clock.moved([now + 40_000_000_000]) == [now + 40_000_000_000 + 10_000_000]
    finally:
        clock.use_script(None)
    assert abs(clock.realtime_ns() - time.time_ns()) < 1_000_000_000
    assert clock.moved([now]) == [now]


def test_the_kernel_is_asked_how_well_the_host_clock_is_synchronised() -> None:
    sync = clock.host_sync()
    assert sync.known, "adjtimex answers on Linux"
    assert sync.host
    assert sync.maximum_error_ns >= 0 and sync.estimated_error_ns >= 0
    if not sync.synchronised:
        assert sync.state in ("not synchronised", "ok") and "not synchronised" in \
            sync.describe()


def test_a_reads_offset_never_puts_a_later_record_first_and_a_step_back_stays() -> None:
    """Records the clock model gives instants 1 ns apart (a refit lowered its line) are
    each put on the realtime clock with their completing read's offset, known to a few
    µs: a later read's may put a later record before an earlier one, and a subscriber
    would see time go back. Such a wobble gives the least later instant; a step of the
    host's clock back (STEP_MIN_NS or more, named as a step) still moves time back."""
    timing = StreamTiming()
    first = timing._onward([1_000_000, 1_000_001])
    wobbled = timing._onward([1_000_002 - 4_000, 1_000_003 - 4_000, 1_010_000])
    assert first + wobbled == [1_000_000, 1_000_001, 1_000_002, 1_000_003, 1_010_000]
    stepped = timing._onward([1_010_000 - STEP_MIN_NS, 1_020_000 - STEP_MIN_NS])
    assert stepped == [1_010_000 - STEP_MIN_NS, 1_020_000 - STEP_MIN_NS]
