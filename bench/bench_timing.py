"""How close the live and offline time_ns get to the true sample instant, on every link.

Synthesises 10-minute captures of several units in virtual time (100 Hz 0xC2, clock
errors of tens of ppm wandering by a few ppm, one timer rollover, units beating
slowly against the host's 1 ms frame clock, exponential OS latency of 0.3-0.8 ms
mean, stalls of 5-40 ms about every 20 s) over each link a GX3 is connected by:
native USB, a UART at 115,200 baud, and a USB-serial adapter at 115,200 baud with a
1 ms and a 16 ms latency timer. Each capture is timed as ``gx3 replay`` times it
(the framer's records and partial reads through ``StreamTiming``: the live
``time_ns``, which replay reproduces bit for bit) and by ``OfflineClock`` over the
whole capture, told the link by the capture's metadata, and again told the link
``infer_transport`` finds in the receive times (a capture without metadata).

Prints, per link, p50 / p99 / max of |time_ns - truth| and its mean after a 30 s
warm-up in microseconds, the spread of the units' mean errors, and whether offline is
at least as good as live (p99 and max) on every unit.

Run: .venv/bin/python bench/bench_timing.py [--seconds 600] [--links usb,uart,...]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, replace

import numpy as np

from bridge.ingest.replay import frame_reads
from bridge.protocol.framer import Framer
from bridge.protocol.table import TICKS_PER_SECOND
from bridge.sim.capture import USB_BAUD, SyntheticCapture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery
from bridge.timing.links import infer_transport
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


def timed(capture: SyntheticCapture, settings: Settings
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _row(err_ns: np.ndarray) -> tuple[float, float, float, float]:
    a = np.abs(err_ns) / 1e3
    return (float(np.percentile(a, 50)), float(np.percentile(a, 99)), float(a.max()),
            float(err_ns.mean()) / 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="capture length")
    parser.add_argument("--links", default=",".join(LINKS),
                        help=f"comma-separated, of {', '.join(LINKS)}")
    args = parser.parse_args()
    for key in args.links.split(","):
        link = LINKS[key]
        told = Settings(CODE, 10, FILTER_WIDTH, link.baud, link.transport)
        print(f"\n{link.name}: {args.seconds:.0f} s at 100 Hz; time_ns - truth after 30 s, us "
              "(p50, p99, max of |error|; mean)")
        print(f"{'unit':27} {'link':16} {'live p50':>8} {'p99':>6} {'max':>6} {'mean':>6} "
              f"{'offline p50':>11} {'p99':>6} {'max':>6} {'mean':>6}")
        means: dict[str, list[float]] = {}
        worse, t0 = [], time.process_time()
        for k, (name, ppm, wander, period, phase, latency, timer_start) in enumerate(UNITS):
            config = streaming_config(UnitConfig(
                clock_ppm=ppm, clock_wander_ppm=wander, clock_wander_period_s=period,
                clock_seed=k, timer_start=timer_start), code=CODE, filter_width=FILTER_WIDTH,
                baud=link.baud)
            capture = synthesize(config, link.delivery(phase, latency, k), args.seconds)
            inferred = infer_transport(capture.rx_ns, capture.data, CODE)
            for source, settings in (("metadata", told),
                                     ("inferred", replace(told, transport=inferred.transport))):
                live, offline, truth = timed(capture, settings)
                late = truth >= truth[0] + WARM_NS
                lv, of = _row((live - truth)[late]), _row((offline - truth)[late])
                said = settings.transport if source == "inferred" else "metadata"
                print(f"{name:27} {said:16} {lv[0]:8.1f} {lv[1]:6.1f} {lv[2]:6.1f} {lv[3]:6.1f} "
                      f"{of[0]:11.1f} {of[1]:6.1f} {of[2]:6.1f} {of[3]:6.1f}")
                means.setdefault(f"live, {source}", []).append(lv[3])
                means.setdefault(f"offline, {source}", []).append(of[3])
                if of[1] > lv[1] or of[2] > lv[2]:
                    worse.append(f"{name} ({source})")
        print("spread of the units' mean errors (max - min), us: "
              + ", ".join(f"{m} {max(v) - min(v):.1f}" for m, v in means.items()))
        print("offline worse than live (p99 or max) on: " + (", ".join(worse) or "no unit")
              + f"; {time.process_time() - t0:.0f} s CPU")


if __name__ == "__main__":
    main()
