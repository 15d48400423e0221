"""The offline smoother: both sides of every record, against the emulator's truth."""

from __future__ import annotations

import numpy as np

from bridge.timing import TimerUnwrapper
from bridge.timing.offline import OfflineClock
from tests.test_timing_clock import FLOOR_NS, FRAME_NS, _capture, _delay_ns, _errors, _run


def _smooth(ppm: float, seconds: float, phase_s: float) -> tuple[np.ndarray, np.ndarray]:
    capture = _capture(ppm, 0.0, seconds, phase_s)
    timer, rx = capture.records()
    ticks = TimerUnwrapper(625).update(timer, rx).ticks
    clock = OfflineClock(_delay_ns(capture), FLOOR_NS, FRAME_NS)
    out = clock.smooth(ticks, rx)
    assert np.array_equal(out, clock.smooth(ticks, rx))
    return _errors(capture, out), _errors(capture, _run(capture))


def test_offline_beats_online_on_a_beating_unit() -> None:
    offline, online = _smooth(1.0, 150.0, 0.00093)
    # The frame crossing after ~100 s pins the line for the records before it too.
    assert np.percentile(offline, 99) < 0.75 * np.percentile(online, 99)
    assert np.percentile(offline, 99) < 350_000


def test_offline_on_a_slow_unit() -> None:
    offline, _ = _smooth(-60.0, 90.0, 0.00077)
    assert np.percentile(offline, 99) < 50_000
