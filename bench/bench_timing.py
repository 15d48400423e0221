"""How close exported and live time_ns get to the truth at every rate, link and crystal.

The matrix a fleet runs at: output rates of 100, 200, 500 and 1000 Hz (0xC2, at 115,200,
230,400, 460,800 and 921,600 baud: the manual's Table 5), each behind a USB-serial
adapter that hands the host every byte at each 1 ms frame and on the unit's own USB
port (and, with ``--links``, on a UART and behind an adapter with a 16 ms latency
timer), with crystals +40, +12, -3 and -55 ppm from the host's (fixed, or wandering with
``--wander``), OS latency exponential with a mean of 0.15-0.3 ms and stalls of 5-40 ms
about every 20 s. Each unit sends its records a fixed processing delay after its filter
window ends; the emulator keeps every sample's true instant.

Each capture is written as a bridge's ``--capture`` file would be, replayed by ``gx3
replay`` and exported with ``gx3 export``'s re-estimate, as a user would, and again
without its metadata (another program's capture: the link, rate and baud inferred from
the bytes). Per cell, from 5 s on, in microseconds: the exported time_ns' bias (mean
error) and its p99 around that bias, its p99 absolute error, and the live time_ns' p99;
then the link ``gx3 replay`` inferred. Last, the spread of the exported biases: units
with the same processing delay should agree whatever their link and crystal.

Run: .venv/bin/python bench/bench_timing.py [--seconds 600] [--rates 100,1000]
     [--links adapter,usb] [--ppm 40,-3] [--wander 0.3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bridge.archive import RawCaptureWriter, capture_metadata, read_archive
from bridge.bus.gx3_pb2 import Info
from bridge.export import offline_times, sample_table
from bridge.ingest import replay
from bridge.sim.capture import USB_BAUD, WALL_NS, SyntheticCapture, streaming_config, synthesize
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import AdapterDelivery, HostDelivery, UartDelivery, UsbDelivery

CODE = 0xC2
FILTER_WIDTH = 15
BAUDS = {100: 115_200, 200: 230_400, 500: 460_800, 1000: 921_600}
PPMS = (40.0, 12.0, -3.0, -55.0)
WARM_NS = 5_000_000_000


@dataclass(frozen=True)
class Cell:
    rate: int
    link: str  # "adapter", "usb", "uart" or "adapter16"
    ppm: float
    index: int  # seeds the cell's latencies, stalls and frame phase

    @property
    def baud(self) -> int:
        return BAUDS[self.rate]

    def delivery(self) -> HostDelivery:
        phase = (0.000377 * (self.index + 1)) % 0.001
        latency = 0.00015 + 0.00005 * (self.index % 4)
        if self.link == "usb":
            return UsbDelivery(frame_phase_s=phase, os_latency_mean_s=latency, seed=self.index)
        if self.link == "uart":
            return UartDelivery(os_latency_mean_s=latency, seed=self.index)
        return AdapterDelivery(frame_phase_s=phase, os_latency_mean_s=latency,
                               seed=self.index, latency_timer_s=self.latency_timer_ms / 1000)

    @property
    def latency_timer_ms(self) -> int:
        return 16 if self.link == "adapter16" else 1

    def capture(self, seconds: float, wander: float) -> SyntheticCapture:
        config = streaming_config(
            UnitConfig(clock_ppm=self.ppm, clock_wander_ppm=wander,
                       clock_wander_period_s=600.0, clock_seed=self.index),
            code=CODE, decimation=1000 // self.rate, filter_width=FILTER_WIDTH,
            baud=USB_BAUD if self.link == "usb" else self.baud)
        return synthesize(config, self.delivery(), seconds)

    def info(self) -> Info:
        """What the unit's bridge would have said of it (the capture's metadata)."""
        link = {"usb": "usb", "uart": "uart"}.get(self.link, "usb-serial")
        return Info(unit="u1", port="/dev/ttyUSB0", baud=self.baud, command=CODE,
                    decimation=1000 // self.rate, filter_width=FILTER_WIDTH, link=link,
                    latency_timer_ms=self.latency_timer_ms if link == "usb-serial" else 0,
                    mode=2)


def exported(capture: SyntheticCapture, folder: Path, metadata: dict[str, str] | None
             ) -> tuple[np.ndarray, np.ndarray, str]:
    """The capture through gx3 replay and gx3 export: exported and live time_ns by ticks."""
    raw, out = folder / "raw.mcap", folder / "out.mcap"
    for path in (raw, out):
        path.unlink(missing_ok=True)
    writer = RawCaptureWriter(raw, "gx3", "u1", metadata)
    boot = WALL_NS - 3_600_000_000_000  # the raw clock counts from an hour before
    for real, data in zip(capture.rx_ns.tolist(), capture.data, strict=True):
        writer.write(data, real, real - boot)
    writer.close()
    result = replay([raw], out)[0]
    archive = read_archive(out)
    table = sample_table(archive, ["u1"], re_estimate=offline_times(archive))
    order = np.argsort(table["ticks"], kind="stable")
    assert result.settings is not None
    link = f"{result.settings.transport} {result.settings.baud}" if result.inferred else ""
    return table["time_ns"][order], table["live_time_ns"][order], link


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0, help="capture length")
    parser.add_argument("--rates", default="100,200,500,1000", help="output rates, Hz")
    parser.add_argument("--links", default="adapter,usb",
                        help="adapter (1 ms latency timer), usb (the unit's own port), uart, "
                             "adapter16 (a 16 ms latency timer)")
    parser.add_argument("--ppm", default=",".join(f"{p:g}" for p in PPMS),
                        help="the crystals' rate errors against the host's")
    parser.add_argument("--wander", type=float, default=0.0,
                        help="ppm the crystals wander by over 10 minutes")
    args = parser.parse_args()
    cells = [Cell(int(r), link, float(p), i)
             for i, (r, link, p) in enumerate((r, link, p) for r in args.rates.split(",")
                                              for link in args.links.split(",")
                                              for p in args.ppm.split(","))]
    print(f"{args.seconds:.0f} s captures of 0x{CODE:02X}; error of time_ns after 5 s, us")
    print(f"{'rate':>5} {'baud':>7} {'link':8} {'ppm':>4} | {'exported bias':>13} {'p99':>6} "
          f"{'p99 abs':>7} {'live p99':>8} | {'no metadata: bias':>17} {'p99':>6} "
          f"{'link inferred':18}")
    biases: list[float] = []
    start = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for cell in cells:
            capture = cell.capture(args.seconds, args.wander)
            truth = capture.truth["value_ns"]
            late = truth >= truth[0] + WARM_NS
            row = []
            for metadata in (capture_metadata(cell.info()), None):
                times, live, link = exported(capture, folder, metadata)
                err = (times - truth)[late] / 1e3
                bias = float(err.mean())
                row.append((bias, float(np.percentile(np.abs(err - bias), 99)),
                            float(np.percentile(np.abs(err), 99)),
                            float(np.percentile(np.abs(live - truth)[late], 99)) / 1e3, link))
            (b, p, a, lv, _), (b2, p2, _, _, inferred) = row
            biases.append(b)
            print(f"{cell.rate:5d} {cell.baud:7d} {cell.link:8} {cell.ppm:+4.0f} | {b:+13.1f} "
                  f"{p:6.1f} {a:7.1f} {lv:8.1f} | {b2:+17.1f} {p2:6.1f} {inferred:14}",
                  flush=True)
    print(f"exported biases: {min(biases):+.1f} to {max(biases):+.1f} us "
          f"(spread {max(biases) - min(biases):.1f} us); "
          f"{time.process_time() - start:.0f} s CPU")


if __name__ == "__main__":
    main()
