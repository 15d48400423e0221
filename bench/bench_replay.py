"""`gx3 replay` speed: a raw capture of UNITS units at RATE Hz for MINUTES, replayed.

Captures come from the emulator in virtual time through the USB delivery model and
are written as a bridge's --capture files; the replay runs them through the framer,
the timing and the archive writer. Reports samples replayed per second and the load
average while it ran (the machine is shared: other work slows it down).

By default the capture metadata names no unit, so the replay finds the settings from
the bytes and times the records as from a serial line; ``--usb`` writes the bridge's
full metadata (unit, USB link), and the replay then runs the USB frame-clock model.

    python bench/bench_replay.py --units 4 --rate 100 --minutes 10 [--usb]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.ingest.replay import replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--units", type=int, default=4)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--usb", action="store_true",
                        help="the bridge's metadata: unit named, USB link timing")
    parser.add_argument("--jobs", type=int, default=0,
                        help="capture files replayed at once, as gx3 replay -j (0: a core each)")
    args = parser.parse_args()
    decimation = round(1000 / args.rate)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i in range(args.units):
            config = streaming_config(UnitConfig(motion=MotionConfig(seed=i), clock_ppm=20.0 * i),
                                      code=0xCC, decimation=decimation)
            cap = synthesize(config, UsbDelivery(seed=i), seconds=args.minutes * 60)
            path = Path(tmp, f"u{i}.mcap")
            meta = {"record": "0xCC", "decimation": str(decimation), "filter_width": "15",
                    "baud": "115200", "transport": "usb"}
            writer = RawCaptureWriter(path, "gx3", f"u{i}",
                                      {"unit": f"u{i}", **meta} if args.usb else meta)
            for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
                writer.write(data, rx)
            writer.close()
            paths.append(path)
        started = time.perf_counter()
        results = replay(paths, Path(tmp, "out.mcap"), jobs=args.jobs or None)
        took = time.perf_counter() - started
        load = os.getloadavg()[0]
    samples = sum(r.samples for r in results)
    print(f"{args.units} units x {args.rate:g} Hz x {args.minutes:g} min"
          f"{' (USB timing)' if args.usb else ''}, {args.jobs or os.cpu_count()} job(s): "
          f"{samples:,} samples replayed in "
          f"{took:.2f} s, {samples / took:,.0f} samples/s (load average {load:.2f})")


if __name__ == "__main__":
    main()
