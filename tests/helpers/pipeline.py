"""The unit pipeline on an emulated unit, in this process, with a sink that keeps everything."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bridge.device.session import UnitInfo
from bridge.sim.serve import Simulator
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from bridge.unit.pipeline import Options, Pipeline, TimedSamples, UnitEvent


@dataclass
class ListSink:
    """A pipeline's sink that keeps what it is given in lists (Zenoh's stand-in)."""

    infos: list[UnitInfo] = field(default_factory=list)
    batches: list[TimedSamples] = field(default_factory=list)
    events: list[UnitEvent] = field(default_factory=list)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    published: list[int] = field(default_factory=list)  # raw-clock time of each samples call
    lock: threading.Lock = field(default_factory=threading.Lock)

    def info(self, info: UnitInfo) -> None:
        self.infos.append(info)

    def samples(self, samples: TimedSamples) -> None:
        with self.lock:
            self.batches.append(samples)
            self.published.append(time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW))

    def event(self, event: UnitEvent) -> None:
        self.events.append(event)

    def status(self, status: dict[str, Any]) -> None:
        self.statuses.append(status)

    def column(self, name: str) -> np.ndarray:
        with self.lock:
            parts = [getattr(s, name) if name in ("ticks", "time_ns", "rx_ns") else
                     s.batch.rx_ns if name == "rx_mono_raw_ns" else s.batch[name]
                     for s in self.batches]
        return np.concatenate(parts) if parts else np.zeros(0)

    def kinds(self) -> list[str]:
        return [e.kind for e in self.events]


@contextmanager
def running(config: UnitConfig, link: Path | None = None, usb: UsbDelivery | None = None,
            transport: str = "pty", **options: Any
            ) -> Iterator[tuple[Simulator, Pipeline, ListSink]]:
    """The pipeline on an emulated unit; ``link`` is a stable name that survives unplugs
    (the kernel may give a replugged pty another number, as udev rules prevent for real);
    ``usb`` how the unit's bytes reach the host; ``transport`` "pty" or "tcp" (a serial
    server, ``socket://``)."""
    with Simulator([config], transport, links=[link] if link else None, usb=usb) as sim:
        sink = ListSink()
        pipeline = Pipeline(Options(url=sim.endpoints[0], **options), sink)
        stop = threading.Event()
        worker = threading.Thread(target=pipeline.run, args=(stop,))
        worker.start()
        try:
            yield sim, pipeline, sink
        finally:
            stop.set()
            worker.join(timeout=30)
            assert not worker.is_alive(), "the pipeline did not stop"
