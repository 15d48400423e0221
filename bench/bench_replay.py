"""`gx3 replay` speed: a raw capture of UNITS units at RATE Hz for MINUTES, replayed.

Captures come from the emulator in virtual time through the USB delivery model and
are written as a bridge's --capture files; the replay runs them through the framer,
the timing and the archive writer. Reports samples replayed per second.

    python bench/bench_replay.py --units 4 --rate 100 --minutes 10
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from bridge.recorder.rawcapture import RawCaptureWriter
from bridge.recorder.replay import replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--units", type=int, default=4)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()
    decimation = round(1000 / args.rate)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for i in range(args.units):
            config = streaming_config(UnitConfig(motion=MotionConfig(seed=i), clock_ppm=20.0 * i),
                                      code=0xCC, decimation=decimation)
            cap = synthesize(config, UsbDelivery(seed=i), seconds=args.minutes * 60)
            path = Path(tmp, f"u{i}.mcap")
            writer = RawCaptureWriter(path, "gx3", f"u{i}", {
                "record": "0xCC", "decimation": str(decimation), "filter_width": "15",
                "baud": "115200", "transport": "usb"})
            for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
                writer.write(data, rx)
            writer.close()
            paths.append(path)
        started = time.perf_counter()
        results = replay(paths, Path(tmp, "out.mcap"))
        took = time.perf_counter() - started
    samples = sum(r.samples for r in results)
    print(f"{args.units} units x {args.rate:g} Hz x {args.minutes:g} min: {samples:,} samples "
          f"replayed in {took:.1f} s, {samples / took:,.0f} samples/s")


if __name__ == "__main__":
    main()
