"""The clock model against the emulator's truth, in virtual time, over USB."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.protocol.table import TICKS_PER_SECOND
from bridge.sim.capture import synthesize
from bridge.timing import OnlineClock, Timeline
from bridge.timing.clock import _lower_hull, support_slope
from tests.helpers.timing import (
    FLOOR_NS,
    FRAME_NS,
    WARM_NS,
    delay_ns,
    late_errors,
    make_timeline,
    online_times,
    phase_for_crossing,
    usb_capture,
)


def test_fast_unit_with_wander_and_a_rollover() -> None:
    capture = usb_capture(80.0, 3.0, 90.0, 0.00041, timer_start=(1 << 32) - 45 * TICKS_PER_SECOND)
    timer, rx = capture.records()
    timeline = make_timeline(capture)
    out = timeline.update(timer, rx)
    assert [e.kind for e in out.events] == ["rollover"]
    err = late_errors(capture, out.time_ns)
    naive = late_errors(capture, rx - delay_ns(capture))
    assert np.percentile(err, 99) < 100_000, np.percentile(err, 99)
    assert np.percentile(naive, 99) > 1_000_000  # the host stamp alone is far off
    state = timeline.state
    rate = capture.config.clock_ppm
    assert abs(state.drift_ppm - rate) < 5.0  # positive: the unit's clock runs fast
    assert 0 < state.spread_ns < 2_000_000 and state.samples > 0


def test_slow_unit() -> None:
    capture = usb_capture(-60.0, 0.0, 90.0, 0.00077)
    assert np.percentile(late_errors(capture, online_times(capture)), 99) < 100_000


def test_a_beating_unit_is_within_the_uncertainty_it_states() -> None:
    # At 12 ppm against the frame clock the unit's phase moves 12 us a second: its
    # records cross a frame boundary every 83 s, here first after 20 s. The unit's own
    # port hands records over whole, so until a crossing nothing tells where in its
    # frame a sample fell, and the hull alone sits up to a frame late; a crossing pins
    # the line there, two pin its rate. The model says how sure it is, and is right.
    capture = usb_capture(12.0, 0.0, 150.0, phase_for_crossing(12.0, 20.0))
    timer, rx = capture.records()
    timeline = make_timeline(capture)
    timeline.clock.fits = []
    result = timeline.update(timer, rx)
    out = result.time_ns
    fits = np.array([t for t, _ in timeline.clock.fits])
    extent = np.array([math.inf] + [e for _, e in timeline.clock.fits])
    doubt = extent[np.searchsorted(fits, result.ticks, side="right")] / 2
    truth = capture.truth["value_ns"]
    err = np.abs(out - truth)
    seconds = (truth - truth[0]) / 1e9
    known = np.isfinite(doubt) & (seconds > 5)
    assert np.mean(err[known] <= doubt[known] + 5_000) > 0.995, "the truth is inside"
    assert np.all(doubt[known & (seconds < 19)] > 300_000), "no crossing yet: doubt"
    assert np.percentile(err[seconds > 110], 99) < 25_000, "two crossings: pinned"
    assert np.all(doubt[seconds > 110] < 50_000)
    envelope = late_errors(capture, online_times(capture, frame_ns=0))
    assert np.percentile(envelope, 99) > 700_000, np.percentile(envelope, 99)


def test_filter_delay_is_taken_out_exactly() -> None:
    capture = usb_capture(-60.0, 0.0, 90.0, 0.00077)
    timer, rx = capture.records()
    plain = Timeline(625, floor_ns=FLOOR_NS, frame_ns=FRAME_NS).update(timer, rx).time_ns
    m15 = Timeline(625, delay_ns=7_000_000, floor_ns=FLOOR_NS,
                   frame_ns=FRAME_NS).update(timer, rx).time_ns
    assert np.array_equal(plain - 7_000_000, m15)
    # Without the delay the estimate is when each record's first byte was on the line:
    # its cycle's instant and the unit's processing delay on; with it, 7 ms earlier.
    truth = capture.truth["time_ns"] + round(capture.config.processing_delay_s * 1e9)
    late = truth >= truth[0] + WARM_NS
    assert np.percentile(np.abs(plain - truth)[late], 99) < 100_000


def test_replay_is_bit_for_bit() -> None:
    a = usb_capture(80.0, 3.0, 40.0, 0.00041, timer_start=(1 << 32) - 20 * TICKS_PER_SECOND)
    b = synthesize(a.config, a.delivery, 40.0)
    assert np.array_equal(a.rx_ns, b.rx_ns) and a.data == b.data
    assert np.array_equal(online_times(a), online_times(b))


def _split_input() -> tuple[np.ndarray, np.ndarray]:
    capture = usb_capture(-60.0, 0.0, 90.0, 0.00077)
    timer, rx = capture.records()
    timer, rx = timer[:2200].copy(), rx[:2200]
    timer[700] ^= np.uint32(1 << 20)  # a corrupt timer
    keep = np.r_[0:1500, 1510:2200]  # and a gap
    return timer[keep], rx[keep]


@settings(max_examples=8, deadline=None)
@given(st.lists(st.integers(1, 2189), max_size=12))
def test_output_does_not_depend_on_how_records_are_split(cuts: list[int]) -> None:
    timer, rx = _split_input()
    whole = Timeline(625, floor_ns=FLOOR_NS, frame_ns=FRAME_NS).update(timer, rx)
    timeline = Timeline(625, floor_ns=FLOOR_NS, frame_ns=FRAME_NS)
    parts = [timeline.update(timer[a:b], rx[a:b])
             for a, b in zip([0, *sorted(cuts)], [*sorted(cuts), len(timer)], strict=True)]
    assert np.array_equal(whole.time_ns, np.concatenate([p.time_ns for p in parts]))
    assert np.array_equal(whole.ticks, np.concatenate([p.ticks for p in parts]))
    assert sum(p.dropped for p in parts) == whole.dropped == 10
    kinds = sorted(e.kind for p in parts for e in p.events)
    assert kinds == sorted(e.kind for e in whole.events) == ["gap", "glitch"]


def test_reset_restarts_the_model_and_keeps_the_rate() -> None:
    capture = usb_capture(-60.0, 0.0, 90.0, 0.00077)
    timer, rx = capture.records()
    clock = OnlineClock(floor_ns=FLOOR_NS, frame_ns=FRAME_NS)
    clock.update(timer[:5000].astype(np.int64), rx[:5000])
    rate = clock.state.drift_ppm
    clock.reset()
    assert clock.state.samples == 0
    shifted = timer[5000:].astype(np.int64) - int(timer[5000])  # the tick base moved
    out = clock.update(shifted, rx[5000:])
    truth = capture.truth["time_ns"][5000:]
    assert abs(clock.state.drift_ppm - rate) < 1.0
    assert np.percentile(np.abs(out - truth)[-1000:], 99) < 600_000


def test_live_instants_never_go_back_when_the_latency_drops() -> None:
    """A busy host delivers the first second 20 ms late, then promptly: the refit lowers
    the line by 20 ms, yet every later sample must be stamped after the one before."""
    n = 3000  # 1 kHz for 3 s
    ticks = np.arange(n, dtype=np.int64) * 62 + 5_000
    true_ns = 1_763_000_000_000_000_000 + ticks * 16_000
    late = np.where(np.arange(n) < 1000, 20_000_000, 50_000)
    clock = OnlineClock()
    one_by_one = np.concatenate([clock.update(ticks[i : i + 1], (true_ns + late)[i : i + 1])
                                 for i in range(n)])
    assert (np.diff(one_by_one) > 0).all()
    settled = one_by_one[-500:] - true_ns[-500:]
    assert np.abs(settled).max() < 1_000_000, "the line catches up with the prompt points"
    at_once = OnlineClock().update(ticks, true_ns + late)
    assert (at_once == one_by_one).all(), "the same whatever the split"


@settings(max_examples=200, deadline=None)
@given(st.integers(2, 3000), st.floats(-120, 120), st.floats(-400, 400), st.integers(0, 2**32))
def test_support_slope_gives_the_highest_line_under_the_points_at_the_middle(
        n: int, ppm: float, prior_error_ppm: float, seed: int) -> None:
    """Whatever the points and however far the prior, the line is the highest under every
    point at the window's middle: as high there as the hull edge over the middle (found
    exactly on integers), to well under a ns, unless that edge is beyond the search's
    +-500 ppm (then as high as the limit allows)."""
    rng = np.random.default_rng(seed)
    x = np.unique(rng.integers(0, 60 * TICKS_PER_SECOND, n)).astype(np.int64)
    late = rng.exponential(rng.uniform(1e3, 3e6), len(x)) * (1 + 40 * (rng.random(len(x)) < 0.01))
    y = (x * (16_000 * (1 + ppm * 1e-6)) + late).astype(np.int64) + 10**15
    mid = int(x[0] + (x[-1] - x[0]) // 2)
    hull = _lower_hull(x.tolist(), y.tolist())
    if len(hull) < 2:
        return
    a, b = next((a, b) for a, b in pairwise(hull) if b[0] > mid)
    prior = 16_000 * (1 + (ppm + prior_error_ppm) * 1e-6)
    dx, dy = (x - mid).astype(np.float64), (y - y[0]).astype(np.float64)
    got = support_slope(dx, dy, prior)
    assert prior * (1 - 500e-6) <= got <= prior * (1 + 500e-6)
    edge = min(max((b[1] - a[1]) / (b[0] - a[0]), prior * (1 - 500e-6)), prior * (1 + 500e-6))
    assert abs(float(np.min(dy - got * dx)) - float(np.min(dy - edge * dx))) < 0.01  # ns


def test_support_slope_stops_at_the_search_limits() -> None:
    """Points that rise faster than any crystal can: the search's edge, not beyond."""
    dx = np.array([-2.0, -1.0, 1.0, 2.0]) * TICKS_PER_SECOND
    dy = dx * 16_000 * 1.01  # +10,000 ppm
    assert support_slope(dx, dy, 16_000.0) == 16_000.0 * (1 + 500e-6)
    assert support_slope(dx, -dy, 16_000.0) == 16_000.0 * (1 - 500e-6)
