"""Raw captures: the exact bytes read from a unit, with the host times of each read.

One MCAP message per read on topic ``<prefix>/<unit>/raw``, logged at its receive time
on the host's realtime clock and published at the same instant on its
``CLOCK_MONOTONIC_RAW``. Replaying a capture through the pipeline gives what the live
run gave, because framing and timing are pure functions of (bytes, receive times). The
file is flushed at least once a second, so a crash loses at most that second, and a
full disk stops the capture, never the bridge. The layout: ``docs/design/archive.md``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any, TypeVar

from mcap.writer import CompressionType, Writer

from bridge.archive.outputs import create_locked
from bridge.bus.gx3_pb2 import Info
from bridge.exceptions import CaptureError, OutputRefused
from bridge.protocol.table import Mode

T = TypeVar("T")
RAW_ENCODING = "application/octet-stream"
FLUSH_EVERY_S = 1.0
#: A raw channel's metadata: which clock its messages' publish times are on.
RAW_CLOCK = {"publish_time": "CLOCK_MONOTONIC_RAW"}
#: Publish times from here on are realtime stamps (an older capture's), not raw ones.
REALTIME_FROM_NS = 10**18
#: A metadata record of an archive whose raw reads came later than its reorder window:
#: such a read is written at the log time of the message before it, so the record keeps
#: its topic, the reads' sequence numbers and their realtime receive times (comma-
#: separated), which replay puts back.
LATE_READS = "gx3.late_reads"


def _raw_topic(prefix: str, unit: str) -> str:
    return f"{prefix}/{unit}/raw"


def capture_metadata(info: Info) -> dict[str, str]:
    """What a capture's reads need to be timed as live: its ``gx3.capture`` metadata.

    A bridge writes it into its --capture file, and ``gx3 replay`` takes it from an
    archive's Info where raw reads came over Zenoh.

    Args:
        info: The unit's Info, as its bridge publishes it.

    Returns:
        The metadata: unit, port, link and the settings that time its records.
    """
    return {"unit": info.unit, "port": info.port, "baud": str(info.baud),
            "record": f"0x{info.command:02X}", "firmware": info.firmware_text,
            "flags": str(info.flags), "filter_width": str(info.filter_width),
            "decimation": str(info.decimation), "transport": info.link or "uart",
            **({"latency_timer_ms": str(info.latency_timer_ms)} if info.latency_timer_ms else {}),
            "polled": str(info.mode == Mode.ACTIVE).lower()}


class RawCaptureWriter:
    """Append reads to an MCAP raw capture.

    Args:
        path: The capture file to create; an existing file is refused.
        prefix: The key prefix of its topic, ``<prefix>/<unit>/raw``.
        unit: The unit's name.
        metadata: The unit and its link (``capture_metadata``), for a replay.
        force: Replace an existing file, unless another process writes it.

    Raises:
        CaptureError: The file exists (without ``force``), another process writes it, or
            it cannot be written.
    """

    def __init__(self, path: Path, prefix: str, unit: str,
                 metadata: dict[str, str] | None = None, force: bool = False) -> None:
        self.path = path
        try:
            self._file: IO[bytes] = create_locked(path, force)
        except OutputRefused as exc:
            raise CaptureError(str(exc)) from None
        except OSError as exc:
            raise CaptureError(f"{path}: cannot write the capture ({exc.strerror}); "
                               "choose a writable path") from None
        self._writer = Writer(self._file, chunk_size=256 * 1024,
                              compression=CompressionType.ZSTD)
        self._guard(self._writer.start, "gx3-raw", "gx3-bridge")
        self._channel = self._guard(self._writer.register_channel, _raw_topic(prefix, unit),
                                    RAW_ENCODING, 0, {"unit": unit, **RAW_CLOCK})
        if metadata:
            self._guard(self._writer.add_metadata, "gx3.capture", dict(metadata))
        self._sequence = 0
        self._flushed = time.monotonic()
        self.reads = 0
        self.bytes = 0
        self.stopped = False  # a write failed: what is on disk stays as it is

    def _guard(self, call: Callable[..., T], *args: Any) -> T:
        try:
            return call(*args)
        except OSError as exc:
            raise CaptureError(f"{self.path}: {exc.strerror or exc}; the capture stops here "
                               "(what was written stays readable)") from None

    def write(self, data: bytes, real_ns: int, raw_ns: int | None = None) -> None:
        """Append one read's bytes, stamped with its receive times.

        Args:
            data: The bytes of the read.
            real_ns: Its receive time on the realtime clock, ns since the epoch.
            raw_ns: Its receive time on the raw monotonic clock; None where not known
                (the realtime stamp is written in its place).

        Raises:
            CaptureError: The write failed: the capture stops there (what was written
                stays readable).
        """
        self._guard(self._writer.add_message, self._channel, real_ns, data,
                    real_ns if raw_ns is None else raw_ns, self._sequence)
        self._sequence += 1
        self.reads += 1
        self.bytes += len(data)
        now = time.monotonic()
        if now - self._flushed >= FLUSH_EVERY_S:
            self._flushed = now
            self._guard(self._writer.flush)

    def close(self) -> None:
        """Finish the file (summary and index); safe to call twice.

        Raises:
            CaptureError: Finishing the file failed.
        """
        if self._file.closed:
            return
        try:
            if not self.stopped:
                self._guard(self._writer.finish)
        finally:
            self._file.close()
