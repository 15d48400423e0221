"""How close the live and offline time_ns get to the true sample instant, on every link.

Synthesises 10-minute captures of several units in virtual time (100 Hz 0xC2, clock
errors of tens of ppm wandering by a few ppm, one timer rollover, units beating
slowly against the host's 1 ms frame clock, exponential OS latency of 0.3-0.8 ms
mean, stalls of 5-40 ms about every 20 s) over each link a GX3 is connected by:
native USB, a UART at 115,200 baud, and a USB-serial adapter at 115,200 baud with a
1 ms and a 16 ms latency timer. Each capture is timed as ``gx3 replay`` times it
(the framer's records and partial reads through ``StreamTiming``: the live
``time_ns``, which replay reproduces bit for bit) and by ``OfflineClock`` over the
whole capture, told the link by the capture's metadata.

Prints, per link, p50 / p99 / max / mean of (time_ns - truth) after a 30 s warm-up in
microseconds, the spread of the units' mean errors, and whether offline is at least
as good as live (p99 and max) on every unit.

Run: .venv/bin/python bench/bench_timing.py [--seconds 600] [--links usb,uart,...]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np

from bridge.protocol.framer import Framer
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.recorder.replay import frame_reads
from bridge.sim.capture import USB_BAUD, Capture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery
from bridge.timing.offline import OfflineClock
from bridge.timing.stream import Settings, StreamTiming

CODE = 0xC2
FILTER_WIDTH = 15
BAUD = 115_200
WARM_NS = 30_000_000_000

#: name, clock ppm, wander ppm, wander period s, frame phase s, OS latency mean s,
#: timer start
UNITS = (
    ("+80 ppm, wander 3, rollover", 80.0, 3.0, 300.0, 0.00041, 0.0003,
     (1 << 32) - 200 * TICKS_PER_SECOND),
    ("-60 ppm, wander 2", -60.0, 2.0, 240.0, 0.00077, 0.0008, 0),
    ("+25 ppm, wander 4", 25.0, 4.0, 400.0, 0.00012, 0.0005, 0),
    ("beating +1 ppm", 1.0, 0.0, 300.0, 0.00093, 0.0008, 0),
    ("beating -2 ppm, wander 0.5", -2.0, 0.5, 300.0, 0.00055, 0.0003, 0),
)


@dataclass(frozen=True)
class Link:
    name: str
    transport: str
    baud: int
    latency_timer_s: float = 0.0

    def delivery(self, phase: float, latency: float, seed: int) -> HostDelivery:
        if self.transport == "usb":
            return UsbDelivery(frame_phase_s=phase, os_latency_mean_s=latency, seed=seed)
        if self.transport == "uart":
            return UartDelivery(os_latency_mean_s=latency, seed=seed)
        return AdapterDelivery(frame_phase_s=phase, os_latency_mean_s=latency, seed=seed,
                               latency_timer_s=self.latency_timer_s)


LINKS = {
    "usb": Link("native USB", "usb", USB_BAUD),
    "uart": Link("UART 115,200 baud", "uart", BAUD),
    "adapter1": Link("USB-serial adapter, 1 ms latency timer", "usb-serial", BAUD, 0.001),
    "adapter16": Link("USB-serial adapter, 16 ms latency timer", "usb-serial", BAUD, 0.016),
}


def timed(capture: Capture, settings: Settings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The capture as ``gx3 replay`` times it: live time_ns, offline time_ns, truth."""
    stream = StreamTiming()
    stream.configure(settings, True)
    framer = Framer([settings.record])
    live, ticks, rx, part_ns, part_bytes = [], [], [], [], []
    for batches in frame_reads(framer, capture.rx_ns, capture.data):
        for batch in batches:
            out = stream.process(batch)
            live.append(out.time_ns)
            ticks.append(out.ticks)
            rx.append(out.batch.rx_ns)
            p, k = out.batch.partial()
            part_ns.append(p)
            part_bytes.append(k)
    clock = OfflineClock(settings.filter_delay_ns, settings.floor_ns, settings.frame_ns,
                         serial=settings.serial)
    offline = clock.smooth(np.concatenate(ticks), np.concatenate(rx), np.concatenate(part_ns),
                           settings.part_lead_ns(np.concatenate(part_bytes)))
    truth = capture.truth["time_ns"] - settings.filter_delay_ns
    return np.concatenate(live), offline, truth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="capture length")
    parser.add_argument("--links", default=",".join(LINKS),
                        help=f"comma-separated, of {', '.join(LINKS)}")
    args = parser.parse_args()
    for key in args.links.split(","):
        link = LINKS[key]
        settings = Settings(CODE, 10, FILTER_WIDTH, link.baud, link.transport)
        print(f"\n{link.name}: {args.seconds:.0f} s at 100 Hz; |time_ns - truth| after 30 s, us")
        print(f"{'unit':30} {'method':8} {'p50':>7} {'p99':>7} {'max':>7} {'mean':>7}")
        means: dict[str, list[float]] = {"live": [], "offline": []}
        worse = []
        t0 = time.process_time()
        for k, (name, ppm, wander, period, phase, latency, timer_start) in enumerate(UNITS):
            config = streaming_config(UnitConfig(
                clock_ppm=ppm, clock_wander_ppm=wander, clock_wander_period_s=period,
                clock_seed=k, timer_start=timer_start), code=CODE, filter_width=FILTER_WIDTH,
                baud=link.baud)
            capture = synthesize(config, link.delivery(phase, latency, k), args.seconds)
            live, offline, truth = timed(capture, settings)
            late = truth >= truth[0] + WARM_NS
            stats = {}
            for method, est in (("live", live), ("offline", offline)):
                err = (est - truth)[late] / 1e3
                a = np.abs(err)
                stats[method] = (np.percentile(a, 99), a.max())
                means[method].append(float(err.mean()))
                print(f"{name:30} {method:8} {np.percentile(a, 50):7.1f} "
                      f"{np.percentile(a, 99):7.1f} {a.max():7.1f} {err.mean():7.1f}")
            if any(o > v for o, v in zip(stats["offline"], stats["live"], strict=True)):
                worse.append(name)
        print("spread of the units' mean errors (max - min), us: "
              + ", ".join(f"{m} {max(v) - min(v):.1f}" for m, v in means.items()))
        print("offline worse than live (p99 or max) on: " + (", ".join(worse) or "no unit")
              + f"; {time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
