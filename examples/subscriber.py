"""A gx3 subscriber that needs only zenoh, protobuf and schemas/gx3.proto (not gx3-bridge).

It compiles the schema at start (grpcio-tools), or imports a module you made once:

    python -m grpc_tools.protoc -I schemas --python_out=. schemas/gx3.proto   # -> gx3_pb2.py

then prints, once a second per unit, the latest sample and how many arrived. Each
message is checked first, as schemas/gx3.proto asks: the CRC-32 of its payload must be
the one in its attachment, and the unit it names must be its key's; those that fail
are counted as rejected, never shown:

    python examples/subscriber.py --connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib
import importlib.resources
import json
import sys
import tempfile
import threading
import time
import zlib
from pathlib import Path
from types import ModuleType
from typing import Any

import zenoh
from google.protobuf.message import DecodeError
from zenoh.ext import HistoryConfig, RecoveryConfig, declare_advanced_subscriber

SCHEMAS = Path(__file__).resolve().parent.parent / "schemas"


def load_messages(schemas: Path, workdir: str) -> ModuleType:
    """gx3_pb2, from a module on sys.path or compiled from the .proto into ``workdir``."""
    try:
        return importlib.import_module("gx3_pb2")
    except ImportError:
        pass
    from grpc_tools import protoc  # type: ignore[import-untyped]

    well_known = importlib.resources.files("grpc_tools") / "_proto"  # descriptor.proto
    if protoc.main(["protoc", f"-I{schemas}", f"-I{well_known}", f"--python_out={workdir}",
                    str(schemas / "gx3.proto")]) != 0:
        raise SystemExit(f"error: protoc could not compile {schemas / 'gx3.proto'}")
    sys.path.insert(0, workdir)
    return importlib.import_module("gx3_pb2")


def intact(zs: zenoh.Sample) -> bool:
    """Whether the payload's CRC-32 is the one its publisher attached (the attachment's
    first 4 bytes, little-endian)."""
    attachment = b"" if zs.attachment is None else zs.attachment.to_bytes()
    return (len(attachment) >= 4 and
            int.from_bytes(attachment[:4], "little") == zlib.crc32(zs.payload.to_bytes()))


def describe(sample: Any) -> str:
    """One line: unit, record, time, and every quantity the record holds."""
    when = datetime.datetime.fromtimestamp(sample.time_ns / 1e9, datetime.UTC)
    parts = [f"{sample.unit} 0x{sample.command:02X} ticks={sample.ticks}",
             f"time={when.isoformat(timespec='milliseconds')}"]
    for field, values in sample.ListFields():
        if field.is_repeated:  # the quantities; the rest are the header's scalars
            parts.append(f"{field.name}={[round(v, 4) for v in values]}")
    return " ".join(parts)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file")
    p.add_argument("--connect", action="append", default=[], help="endpoint, e.g. tcp/HOST:7447")
    p.add_argument("--key", default="gx3/*/imu")
    p.add_argument("--schemas", type=Path, default=SCHEMAS)
    p.add_argument("--lines", type=int, default=0, help="stop after this many lines (0: never)")
    args = p.parse_args()
    config = (zenoh.Config.from_file(args.zenoh_config) if args.zenoh_config
              else zenoh.Config())
    if args.connect:
        config.insert_json5("connect/endpoints", json.dumps(args.connect))
    config.insert_json5("scouting/multicast/enabled", "false")

    with tempfile.TemporaryDirectory() as workdir:
        gx3 = load_messages(args.schemas, workdir)
        latest: dict[str, Any] = {}
        counts: dict[str, int] = {}
        misses = [0]
        rejected = [0]
        lock = threading.Lock()

        def on_sample(zs: zenoh.Sample) -> None:
            sample = None
            if intact(zs):
                with contextlib.suppress(DecodeError):
                    sample = gx3.ImuSample.FromString(zs.payload.to_bytes())
            if sample is None or sample.unit != str(zs.key_expr).split("/")[-2]:
                with lock:
                    rejected[0] += 1
                return
            with lock:
                latest[sample.unit] = sample
                counts[sample.unit] = counts.get(sample.unit, 0) + 1

        def on_miss(miss: Any) -> None:
            with lock:
                misses[0] += miss.nb

        printed = 0
        with zenoh.open(config) as session:
            declared: dict[str, Any] = {}

            def on_publisher(token: zenoh.Sample) -> None:
                # Each unit's publisher announces itself under its key (KEY/@adv/pub/...).
                # Declaring that key here lets Zenoh route its samples from a cache; else
                # it searches every unit's announcements per sample (slow with many units).
                key = str(token.key_expr).split("/@adv/pub/", 1)[0]
                if token.kind == zenoh.SampleKind.PUT and key not in declared:
                    declared[key] = session.declare_keyexpr(key)

            publishers = session.liveliness().declare_subscriber(
                f"{args.key}/@adv/pub/**", on_publisher, history=True)
            sub = declare_advanced_subscriber(
                session, args.key, on_sample, history=HistoryConfig(detect_late_publishers=True),
                recovery=RecoveryConfig(heartbeat=True, periodic_queries=None))
            listener = sub.sample_miss_listener(on_miss)
            try:
                while not args.lines or printed < args.lines:
                    time.sleep(1.0)
                    with lock:
                        ready = sorted(latest.items())
                        rates = dict(counts)
                        latest.clear()
                        counts.clear()
                    for unit, sample in ready:
                        print(f"{describe(sample)} ({rates[unit]}/s, missed {misses[0]}, "
                              f"rejected {rejected[0]})", flush=True)
                        printed += 1
            except KeyboardInterrupt:
                pass
            listener.undeclare()
            sub.undeclare()
            publishers.undeclare()
    return 0


if __name__ == "__main__":
    sys.exit(main())
