"""How close each way of stamping records gets to the true sample instant.

Synthesises 10-minute USB captures of several units in virtual time (clock
errors of tens of ppm wandering by a few ppm, one timer rollover, units beating
slowly against the USB frame clock, 1 ms frames, exponential OS latency, stalls
of 5-40 ms) and prints p50 / p99 / max |time_ns - truth| after a 30 s warm-up:

- naive: the host receive time of the read;
- envelope: the min-latency envelope (lower hull of receive times, 60 s window);
- ros: the microstrain_3dmgx2_imu driver's filterTime (mean of 100 offsets into a
  fixed-gain offset/drift filter);
- online: bridge.timing.OnlineClock (what a live subscriber sees);
- offline: bridge.timing.offline.OfflineClock over the whole capture;
- one line: a single lower-hull line over the whole capture.

Run: .venv/bin/python bench/bench_timing.py [--seconds 600]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np

from bridge.protocol.table import REPLIES, TICKS_PER_SECOND
from bridge.sim.capture import Capture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from bridge.timing import OnlineClock, Timeline
from bridge.timing.clock import support_slope
from bridge.timing.offline import OfflineClock

CODE = 0xC2
FRAME_NS = 1_000_000
FLOOR_NS = REPLIES[CODE].length * 1_000  # the emulated USB moves 1 MB/s
WARM_NS = 30_000_000_000

#: name, clock ppm, wander ppm, wander period s, frame phase s, timer start
UNITS = (
    ("+80 ppm, wander 3, rollover", 80.0, 3.0, 300.0, 0.00041, (1 << 32) - 200 * TICKS_PER_SECOND),
    ("-60 ppm, wander 2", -60.0, 2.0, 240.0, 0.00077, 0),
    ("+25 ppm, wander 4", 25.0, 4.0, 400.0, 0.00012, 0),
    ("beating +1 ppm", 1.0, 0.0, 300.0, 0.00093, 0),
    ("beating -2 ppm, wander 0.5", -2.0, 0.5, 300.0, 0.00055, 0),
)

Method = Callable[[Capture, np.ndarray, np.ndarray], np.ndarray]


def _delay(capture: Capture) -> int:
    return (capture.config.stored.sampling.filter_width - 1) * 500_000


def naive(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    return rx - _delay(capture)


def envelope(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    return OnlineClock(_delay(capture), FLOOR_NS, 0, window_s=60.0).update(ticks, rx)


def ros(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """filterTime of the microstrain_3dmgx2_imu ROS driver, on device seconds."""
    k1, k2, n_sum = 0.00995031, 0.0000497506, 100
    imu = (ticks - ticks[0]) / TICKS_PER_SECOND
    sys_s = (rx - rx[0]) / 1e9
    out = np.empty(len(ticks))
    offset = d_offset = sum_meas = 0.0
    counter = 0
    offset = imu[0] - sys_s[0]
    for i in range(len(ticks)):
        if counter < n_sum:
            counter += 1
            sum_meas += imu[i] - sys_s[i]
        else:
            offset += d_offset
            diff = sum_meas / n_sum - offset
            offset += k1 * diff
            d_offset += k2 * diff
            counter, sum_meas = 0, 0.0
        out[i] = imu[i] - offset
    return np.asarray(rx[0] + np.round(out * 1e9).astype(np.int64) - _delay(capture))


def online(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    return OnlineClock(_delay(capture), FLOOR_NS, FRAME_NS).update(ticks, rx)


def offline(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    return OfflineClock(_delay(capture), FLOOR_NS, FRAME_NS).smooth(ticks, rx)


def one_line(capture: Capture, ticks: np.ndarray, rx: np.ndarray) -> np.ndarray:
    dx = (ticks - ticks[0]).astype(np.float64)
    dy = (rx - rx[0] - FLOOR_NS).astype(np.float64)
    rate = support_slope(dx - dx[-1] / 2, dy, 16_000.0)
    level = float(np.min(dy - rate * dx))
    return np.asarray(rx[0] + np.round(level + rate * dx).astype(np.int64) - _delay(capture))


METHODS: tuple[tuple[str, Method], ...] = (
    ("naive", naive), ("envelope", envelope), ("ros", ros), ("online", online),
    ("offline", offline), ("one line", one_line))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="capture length")
    args = parser.parse_args()
    print(f"{args.seconds:.0f} s captures, 100 Hz, USB 1 ms frames, latency mean 0.3 ms, "
          "stalls 5-40 ms every ~20 s; |time_ns - truth| after 30 s, microseconds")
    print(f"{'unit':30} {'method':9} {'p50':>8} {'p99':>8} {'max':>8} {'mean':>8} "
          f"{'us/1k rec':>10}")
    means: dict[str, list[float]] = {}
    for k, (name, ppm, wander, period, phase, timer_start) in enumerate(UNITS):
        config = streaming_config(UnitConfig(
            clock_ppm=ppm, clock_wander_ppm=wander, clock_wander_period_s=period,
            clock_seed=k, timer_start=timer_start), code=CODE)
        capture = synthesize(config, UsbDelivery(frame_phase_s=phase, seed=k), args.seconds)
        timer, rx = capture.records()
        unwrapped = Timeline(625).unwrapper.update(timer, rx)
        ticks = unwrapped.ticks
        truth = capture.truth["time_ns"] - _delay(capture)
        late = truth >= truth[0] + WARM_NS
        for method, fn in METHODS:
            t0 = time.process_time()
            est = fn(capture, ticks, rx)
            cpu = (time.process_time() - t0) / len(ticks) * 1e9  # us per 1,000 records
            err = (est - truth)[late]
            a = np.abs(err) / 1e3
            means.setdefault(method, []).append(float(err.mean()) / 1e3)
            print(f"{name:30} {method:9} {np.percentile(a, 50):8.1f} {np.percentile(a, 99):8.1f} "
                  f"{a.max():8.1f} {err.mean() / 1e3:8.1f} {cpu:10.0f}")
        print()
    print("spread of the units' mean errors (max - min), us:")
    for method, m in means.items():
        print(f"  {method:9} {max(m) - min(m):8.1f}")


if __name__ == "__main__":
    main()
