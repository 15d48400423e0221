"""What a message must show before it is archived or handed to an app.

An intact payload (its CRC-32 travels in the put's attachment) that agrees with its key.

Zenoh 1.10 can splice wire bytes into a payload when a BLOCK put outlives
``wait_before_close``, and some such payloads still parse; a checksum computed by the
publisher over the very bytes it put catches them end to end.

Attachment of every message on a data key (``imu``, ``status``, ``event``, ``raw``) and
of the ``info`` queryable's replies, little-endian (schemas/gx3.proto says the same for
apps in other languages):

- bytes 0-3: CRC-32 of the payload (IEEE 802.3 / zlib / PNG polynomial), uint32;
- bytes 4-11, raw reads: the host receive time of the read; one imu put in 16
  (``bridge.bus.publish.STAMP_EVERY``; absent on the others): the host time it was put;
  int64 ns since the Unix epoch;
- bytes 12-19, raw reads only: the same instant on the host's ``CLOCK_MONOTONIC_RAW``,
  int64 ns (older bridges leave it out).

Readers ignore any bytes beyond those they know, so fields can be added at the end.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Sequence

from google.protobuf.message import DecodeError

from bridge.bus.codec import units_agree
from bridge.bus.gx3_pb2 import Event, Info, Status

#: Key leaves whose messages carry the checksum.
SEALED = ("imu", "status", "event", "raw", "info")
_CRC = struct.Struct("<I")
_CRC_TIME = struct.Struct("<Iq")
_CRC_TIMES = struct.Struct("<Iqq")
_TYPED: dict[str, type[Status] | type[Event] | type[Info]] = {
    "status": Status, "event": Event, "info": Info}

#: Why a message was rejected.
BAD_CHECKSUM = "checksum"
NOT_OF_KEY = "key"


def seal(payload: bytes, rx_ns: int | None = None, raw_ns: int | None = None) -> bytes:
    """The attachment of a payload: its CRC-32, then a raw read's receive times.

    Or, for one imu put in 16, the instant it was put.

    Args:
        payload: The message's bytes.
        rx_ns: A raw read's receive time on the realtime clock, or when a stamped imu
            put was put; None: neither.
        raw_ns: The same instant on the raw monotonic clock (None: left out).

    Returns:
        The attachment's bytes (layout above).
    """
    crc = zlib.crc32(payload)
    if rx_ns is None:
        return _CRC.pack(crc)
    return _CRC_TIME.pack(crc, rx_ns) if raw_ns is None else _CRC_TIMES.pack(crc, rx_ns, raw_ns)


def seals(payloads: Sequence[bytes]) -> list[bytes]:
    """``seal`` of many payloads (no receive times)."""
    pack, crc32 = _CRC.pack, zlib.crc32
    return [pack(crc32(p)) for p in payloads]


def intact(payload: bytes, attachment: bytes | None) -> bool:
    """Whether ``attachment`` holds the CRC-32 of ``payload``.

    Args:
        payload: The message's bytes.
        attachment: Its attachment, if it had one.

    Returns:
        True if the checksums agree; no attachment is not intact.
    """
    return (attachment is not None and len(attachment) >= 4
            and _CRC.unpack_from(attachment)[0] == zlib.crc32(payload))


def read_time(attachment: bytes | None) -> int | None:
    """The host time an attachment carries: a raw read's receipt, a stamped imu put's.

    Args:
        attachment: The attachment, if the message had one.

    Returns:
        Realtime ns since the Unix epoch; None: it carries none.
    """
    if attachment is None or len(attachment) < _CRC_TIME.size:
        return None
    return int(_CRC_TIME.unpack_from(attachment)[1])


def read_raw_time(attachment: bytes | None) -> int | None:
    """The raw-clock receive time a raw read's attachment carries.

    Args:
        attachment: The attachment, if the message had one.

    Returns:
        ``CLOCK_MONOTONIC_RAW`` ns; None: an older bridge's, with none.
    """
    if attachment is None or len(attachment) < _CRC_TIMES.size:
        return None
    return int(_CRC_TIMES.unpack_from(attachment)[2])


def agree(unit: str, leaf: str, payloads: Sequence[bytes]) -> list[bool]:
    """Which payloads are messages of ``leaf``'s type that name ``unit``, the unit of their key.

    A raw read names none; a leaf that is not gx3's is not checked.
    """
    if leaf == "imu":
        return units_agree(unit, payloads)
    cls = _TYPED.get(leaf)
    if cls is None:
        return [True] * len(payloads)
    out = []
    for payload in payloads:
        try:
            out.append(cls.FromString(payload).unit == unit)
        except DecodeError:
            out.append(False)
    return out
