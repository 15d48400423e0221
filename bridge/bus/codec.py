"""ImuSample bytes in bulk: one NumPy record per message, byte-identical to protobuf.

Every ImuSample of one record type from one unit has one layout (schemas/gx3.proto
makes the header fixed-width with explicit presence and the quantities packed
fixed-width arrays), so n samples are one structured array: tags and lengths are
constant bytes, the values are columns. Encoding or decoding a batch is then a
few array copies instead of n protobuf objects. tests/test_bus_codec.py checks
the bytes against the protobuf library for every record type.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import Any, Protocol, cast

import numpy as np
from google.protobuf.descriptor import FieldDescriptor
from google.protobuf.message import DecodeError

from bridge.bus import gx3_pb2
from bridge.bus.gx3_pb2 import ImuSample
from bridge.protocol.codec import reply_dtype
from bridge.protocol.table import DATA_CODES, QUANTITIES, REPLIES

#: Columns every sample carries besides its quantities.
HEADER = ("command", "timer", "ticks", "time_ns", "rx_ns", "rx_mono_raw_ns",
          "part_rx_mono_raw_ns", "part_lead_ns")
#: The headers of older bridges' samples, newest first: without the partial read
#: (``part_rx_mono_raw_ns`` 0), and before reads were stamped on the raw clock too
#: (``rx_mono_raw_ns`` 0). Their messages have bulk layouts of their own, read as fast.
LEGACY_HEADERS = (HEADER[:-2], HEADER[:-3])
#: Every bulk layout a sample may have, newest first.
HEADERS = (HEADER, *LEGACY_HEADERS)
_FIELDS = ImuSample.DESCRIPTOR.fields_by_name
_NUMPY = {FieldDescriptor.TYPE_FIXED32: "<u4", FieldDescriptor.TYPE_SFIXED64: "<i8",
          FieldDescriptor.TYPE_FLOAT: "<f4"}
_WIRE_TYPE = {"<u4": 5, "<f4": 5, "<i8": 1}
_LENGTH_DELIMITED = 2


class RecordBatch(Protocol):
    """What publishing needs of a block of decoded records (bridge.protocol.codec.Batch)."""

    code: int
    rx_ns: np.ndarray  # host receive time of the read that completed each record
    little_endian: bool  # float byte order of ``block``
    block: np.ndarray | None  # the records' wire bytes, (n, length) uint8, if known

    def __len__(self) -> int: ...

    def __getitem__(self, name: str, /) -> np.ndarray: ...


def record_quantities(code: int) -> tuple[str, ...]:
    """The quantities a data record holds, in wire order.

    Args:
        code: The data record (0xC2, 0xCC, ...).

    Returns:
        Their names (``accel``, ``ang_rate``, ...), the timer left out.

    Raises:
        ValueError: ``code`` is not a data record.
    """
    if code not in DATA_CODES:
        raise ValueError(f"0x{code:02X} is not a data record; data records are "
                         + ", ".join(f"0x{c:02X}" for c in sorted(DATA_CODES)))
    return tuple(f.name for f in REPLIES[code].fields if f.name != "timer")


def elements(name: str) -> int:
    """The element count schemas/gx3.proto declares for a quantity field."""
    # the generated stub types extensions as plain FieldDescriptors
    return int(_FIELDS[name].GetOptions().Extensions[cast(Any, gx3_pb2.elements)])


def _varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _tag(name: str, wire_type: int) -> bytes:
    return _varint(_FIELDS[name].number << 3 | wire_type)


@dataclass(frozen=True)
class Layout:
    """The byte layout of the ImuSample messages of one record type from one unit."""

    unit: str
    code: int
    quantities: tuple[str, ...]
    dtype: np.dtype
    template: np.ndarray  # one record: every tag and length set, values zero
    const_mask: np.ndarray  # per byte: True where the byte is a tag or a length

    @property
    def size(self) -> int:
        """Bytes of one message."""
        return int(self.dtype.itemsize)


@functools.cache
def layout(code: int, unit: str, header: tuple[str, ...] = HEADER) -> Layout:
    """The message layout of record type ``code`` published by ``unit``.

    ``header``: one of ``LEGACY_HEADERS`` for an older bridge's.
    """
    quantities = tuple(record_quantities(code))
    name = unit.encode()
    parts: list[tuple[Any, ...]] = []
    consts: dict[str, bytes] = {}

    def const(key: str, raw: bytes) -> None:
        parts.append((key, f"V{len(raw)}"))
        consts[key] = raw

    const("_unit", _tag("unit", _LENGTH_DELIMITED) + _varint(len(name)) + name)
    # protobuf writes fields in field-number order, not in the record's wire order
    for col in sorted((*header, *quantities), key=lambda f: _FIELDS[f].number):
        kind = _NUMPY[_FIELDS[col].type]
        if col in header:
            const(f"_{col}", _tag(col, _WIRE_TYPE[kind]))
            parts.append((col, kind))
            continue
        count = elements(col)
        const(f"_{col}", _tag(col, _LENGTH_DELIMITED) + _varint(4 * count))
        parts.append((col, kind, (count,)))
    dtype = np.dtype(parts)
    template = np.zeros(1, dtype)
    mask = np.zeros(dtype.itemsize, bool)
    for key, raw in consts.items():
        template[key] = np.void(raw)
        offset = dtype.fields[key][1]  # type: ignore[index]
        mask[offset : offset + len(raw)] = True
    template["command"] = code
    mask[dtype.fields["command"][1] : dtype.fields["command"][1] + 4] = True  # type: ignore[index]
    return Layout(unit, code, tuple(sorted(quantities, key=lambda q: _FIELDS[q].number)),
                  dtype, template, mask)


@functools.cache
def _byte_map(code: int, unit: str, little_endian: bool) -> tuple[np.ndarray, np.ndarray]:
    """Where each byte of the timer and the quantities of a wire record lands in its ImuSample.

    Returned as (message positions, record positions). The message holds every value in
    4 little-endian bytes; a wire value may be shorter (the upper bytes stay zero, as in
    the template) and big-endian (its bytes are reversed on the way).
    """
    lay = layout(code, unit)
    wire = reply_dtype(code, little_endian)
    dst: list[int] = []
    src: list[int] = []
    for name in ("timer", *lay.quantities):
        kind, at = wire.fields[name][:2]  # type: ignore[index]
        to = lay.dtype.fields[name][1]  # type: ignore[index]
        width = kind.base.itemsize
        for k in range(kind.itemsize // width):
            for b in range(width):
                dst.append(to + 4 * k + b)
                src.append(at + width * k + (width - 1 - b if kind.base.byteorder == ">" else b))
    return np.array(dst), np.array(src)


#: The int64 columns a message gets besides its record's bytes, in the order
#: ``encode_records`` and the compiled core take them.
TIMES = ("ticks", "time_ns", "rx_ns", "rx_mono_raw_ns", "part_rx_mono_raw_ns", "part_lead_ns")


@functools.cache
def native_layout(code: int, unit: str, little_endian: bool
                  ) -> tuple[bytes, bytes, tuple[int, ...]]:
    """``layout`` and ``_byte_map`` as the compiled core reads them (``bridge/_records.c``).

    The message template, the byte moves as little-endian uint16 pairs (message position,
    record position), and where each of ``TIMES`` goes.
    """
    lay = layout(code, unit)
    dst, src = _byte_map(code, unit, little_endian)
    fields = cast(dict[str, tuple[np.dtype, int]], lay.dtype.fields)
    if any(fields[name][0] != np.dtype("<i8") for name in TIMES):
        raise ValueError(f"0x{code:02X}: the message's times are not little-endian int64")
    at = tuple(fields[name][1] for name in TIMES)
    moves = np.stack([dst, src], axis=1).astype("<u2").tobytes()
    return lay.template.tobytes(), moves, at


def encode_batch(unit: str, batch: RecordBatch, ticks: np.ndarray, time_ns: np.ndarray,
                 rx_ns: np.ndarray, rx_mono_raw_ns: np.ndarray | None = None,
                 part: tuple[np.ndarray, np.ndarray] | None = None) -> list[bytes]:
    """One serialized ImuSample per record of ``batch``: what protobuf would produce.

    Records that came off the wire are moved byte by byte from their wire bytes, with
    no decoding: a live bridge encodes a record or two per read.

    Args:
        unit: The unit's name.
        batch: The records (a ``bridge.protocol.Batch``).
        ticks: Each record's unwrapped ticks.
        time_ns: Each record's sample instant (realtime ns).
        rx_ns: The realtime receive time of the read that completed each.
        rx_mono_raw_ns: The same on the raw monotonic clock; None: not known, 0.
        part: Each record's partial read (``part_rx_mono_raw_ns``, ``part_lead_ns``); None:
            not recorded.

    Returns:
        The messages, in record order.
    """
    if not len(batch):
        return []
    lay = layout(batch.code, unit)
    recs = np.frombuffer(bytearray(lay.template.tobytes() * len(batch)), lay.dtype)
    if batch.block is not None:
        dst, src = _byte_map(batch.code, unit, batch.little_endian)
        recs.view(np.uint8).reshape(len(batch), -1)[:, dst] = batch.block[:, src]
    else:
        recs["timer"] = batch["timer"]
        for q in lay.quantities:
            recs[q] = np.reshape(batch[q], (len(batch), -1))
    recs["ticks"] = ticks
    recs["time_ns"] = time_ns
    recs["rx_ns"] = rx_ns
    if rx_mono_raw_ns is not None:
        recs["rx_mono_raw_ns"] = rx_mono_raw_ns
    if part is not None:
        recs["part_rx_mono_raw_ns"], recs["part_lead_ns"] = part
    buf = recs.tobytes()
    size = lay.size
    return [buf[i : i + size] for i in range(0, len(buf), size)]


class _RecordPacker:
    """``encode_batch`` of one wire record in plain Python.

    Unpack its timer and quantities as integers of their wire width and byte order, pack
    them with the message's tags and lengths, little-endian, 4 bytes each. Integers keep
    every bit (a float would lose a NaN's payload), so the bytes are those ``_byte_map``
    moves. Both Structs are derived from ``layout`` and ``reply_dtype``: the table stays
    the one definition.
    """

    def __init__(self, code: int, unit: str, little_endian: bool) -> None:
        lay = layout(code, unit)
        wire = reply_dtype(code, little_endian)
        fields = cast(dict[str, tuple[np.dtype, int]], wire.fields)
        chars = {1: "B", 2: "H", 4: "I"}
        orders = set()
        wire_fmt = ""
        at: dict[str, int] = {}  # where each quantity's first value lands in the unpacked tuple
        count = 0
        start = 1
        for name in wire.names or ():
            if name in ("code", "timer", "checksum"):
                continue
            kind, offset = fields[name][:2]
            if name not in lay.quantities or offset != start:
                raise ValueError(f"0x{code:02X}: {name} is not a packed quantity at byte {start}")
            width = kind.base.itemsize
            orders.add(kind.base.str[0] if width > 1 else ">")
            at[name] = count
            count += kind.itemsize // width
            wire_fmt += f"{kind.itemsize // width}{chars[width]}"
            start = offset + kind.itemsize
        if len(orders) != 1:
            raise ValueError(f"0x{code:02X}: quantities in more than one byte order")
        self._values = struct.Struct(orders.pop() + wire_fmt).unpack_from
        self._timer = struct.Struct(">I").unpack_from
        self._timer_at = fields["timer"][1]
        # the unpacked tuple, extended: quantities, timer, the times, constants
        tail = {"timer": count, **{name: count + 1 + i for i, name in enumerate(TIMES)}}
        consts: list[bytes | int] = []
        msg_fmt = "<"
        picks: list[int] = []
        message = cast(dict[str, tuple[np.dtype, int]], lay.dtype.fields)
        template = lay.template.tobytes()
        for name in lay.dtype.names or ():
            kind, offset = message[name][:2]
            if name.startswith("_"):
                picks.append(count + len(tail) + len(consts))
                consts.append(template[offset : offset + kind.itemsize])
                msg_fmt += f"{kind.itemsize}s"
            elif name == "command":
                picks.append(count + len(tail) + len(consts))
                consts.append(code)
                msg_fmt += "I"
            elif name in tail:
                picks.append(tail[name])
                msg_fmt += "q" if kind.itemsize == 8 else "I"
            else:
                picks += range(at[name], at[name] + kind.itemsize // 4)
                msg_fmt += f"{kind.itemsize // 4}I"
        self._consts = tuple(consts)
        self._pick: Callable[[tuple[Any, ...]], tuple[Any, ...]] = itemgetter(*picks)
        self._message = struct.Struct(msg_fmt).pack
        if struct.calcsize(msg_fmt) != lay.size:
            raise ValueError(f"0x{code:02X}: message layout of {lay.size} bytes, "
                             f"packed as {struct.calcsize(msg_fmt)}")

    def pack(self, record: bytes, times: tuple[int, ...]) -> bytes:
        """The message of one wire record with ``TIMES``' values, in that order."""
        values = (*self._values(record, 1), self._timer(record, self._timer_at)[0], *times,
                  *self._consts)
        return self._message(*self._pick(values))


_packer = functools.cache(_RecordPacker)


def encode_records(unit: str, code: int, little_endian: bool, records: Iterable[bytes],
                   times: Sequence[Iterable[int]]) -> list[bytes]:
    """``encode_batch`` of wire records held as bytes, one each.

    A live bridge gets one or two a read, for which array set-up costs more than the
    work. ``times``: one list per column of ``TIMES``, in that order.
    """
    pack = _packer(code, unit, little_endian).pack
    return [pack(r, t) for r, t in zip(records, zip(*times, strict=True), strict=True)]


def units_agree(unit: str, payloads: Sequence[bytes]) -> list[bool]:
    """Which serialized ImuSamples name ``unit`` as every protobuf parser reads them.

    A repeated ``unit`` field counts as its last value. A message in the bulk layout of
    its record type is judged by its constant bytes, any other by parsing it; bytes that
    are not an ImuSample name no unit.

    The constant bytes are compared as one masked integer per message: a recorder that
    hears samples promptly checks a message or two per key at a time, where NumPy's
    set-up would cost ten times the check itself.
    """
    out = [False] * len(payloads)
    sizes = set(map(len, payloads))
    code = _peek_command(unit, payloads[0]) if len(sizes) == 1 else None
    if code is not None:
        mask, want = _constants(code, unit)
        from_bytes = int.from_bytes
        out = [from_bytes(p, "big") & mask == want for p in payloads]
        if all(out):
            return out
    for i, fits in enumerate(out):
        if fits:
            continue
        try:
            out[i] = ImuSample.FromString(payloads[i]).unit == unit
        except DecodeError:
            out[i] = False
    return out


def _peek_command(unit: str, payload: bytes) -> int | None:
    """The record type of an ImuSample of ``unit`` in that type's bulk layout.

    Judged by its first bytes and length; None: it is not in one.
    """
    name = unit.encode()
    head = _head(name)
    if not payload.startswith(head) or len(payload) < len(head) + 4:
        return None
    code = int.from_bytes(payload[len(head) : len(head) + 4], "little")
    if code not in DATA_CODES or len(payload) != layout(code, unit).size:
        return None
    return code


@functools.cache
def _constants(code: int, unit: str) -> tuple[int, int]:
    """The constant bytes of ``layout(code, unit)`` as integers.

    The tags, lengths, unit and command as a mask over a message read as one big-endian
    integer, and the bytes they must hold there.
    """
    lay = layout(code, unit)
    const = lay.const_mask
    template = lay.template.view(np.uint8)
    return (int.from_bytes(np.where(const, 0xFF, 0).astype(np.uint8).tobytes(), "big"),
            int.from_bytes(np.where(const, template, 0).astype(np.uint8).tobytes(), "big"))


@functools.cache
def _head(name: bytes) -> bytes:
    return _tag("unit", _LENGTH_DELIMITED) + _varint(len(name)) + name + _tag("command", 5)


def peek(payload: bytes) -> tuple[str, int]:
    """The unit and record type of a serialized ImuSample, without decoding its values.

    Read from its first bytes when it has the bulk layout, else by parsing it.

    Args:
        payload: The message.

    Returns:
        (unit, command).

    Raises:
        ValueError: The bytes are not an ImuSample.
    """
    if payload[:1] == b"\x0a" and len(payload) > 2 and payload[1] < 0x80:
        end = 2 + payload[1]
        if payload[end : end + 1] == b"\x15" and len(payload) >= end + 5:
            return payload[2:end].decode(), int.from_bytes(payload[end + 1 : end + 5], "little")
    msg = parse(payload)
    return msg.unit, msg.command


def parse(payload: bytes) -> ImuSample:
    """One ImuSample.

    Args:
        payload: The serialized message.

    Returns:
        The message.

    Raises:
        ValueError: The bytes are not an ImuSample; the message says so in one line.
    """
    try:
        return ImuSample.FromString(payload)
    except DecodeError as exc:
        raise ValueError(f"not a gx3.v1.ImuSample ({len(payload)} bytes): {exc}") from None


def decode_batch(unit: str, code: int,
                 payloads: Sequence[bytes] | np.ndarray) -> dict[str, np.ndarray]:
    """Columns of serialized ImuSamples of one unit and record type.

    Messages in the bulk layout (or an older bridge's, ``LEGACY_HEADERS``) are read as one
    array; any other valid encoding of the same message (another
    producer's field order, say) is parsed one by one.

    Args:
        unit: The unit the messages name.
        code: Their record type.
        payloads: The messages; or an (n, layout size) uint8 array, one message per row
            (read straight out of a buffer, without a bytes object each).

    Returns:
        The header (``HEADER``) and each quantity by name, shaped as in the command table
        (``m`` is (n, 3, 3)).

    Raises:
        ValueError: A message is not an ImuSample, or is of another unit or type.
    """
    lay = layout(code, unit)
    n = len(payloads)
    if isinstance(payloads, np.ndarray):
        size = payloads.size // n if n else lay.size
        header = next((h for h in HEADERS if layout(code, unit, h).size == size), HEADER)
        bulk = layout(code, unit, header)
        raw = payloads.reshape(n, -1)
        good = _constant_bytes_hold(bulk, raw) if bulk.size == raw.shape[1] \
            else np.zeros(n, bool)
        if header == HEADER and good.all() and raw.flags.c_contiguous:
            return _columns(lay, raw.reshape(-1).view(lay.dtype))  # every row as it is
    recs = np.zeros(n, lay.dtype)
    if isinstance(payloads, np.ndarray):
        rows = raw[good].reshape(-1).view(bulk.dtype)
        for name in (*header, *bulk.quantities):
            recs[name][good] = rows[name]
        todo = np.flatnonzero(~good)
    else:
        todo = np.arange(n)
        for header in HEADERS:
            if not len(todo):
                break
            bulk = layout(code, unit, header)
            done, rows = _bulk_rows(bulk, [payloads[i] for i in todo.tolist()])
            for name in (*header, *bulk.quantities):
                recs[name][todo[done]] = rows[name]
            todo = np.delete(todo, done)
    for i in todo.tolist():
        msg = parse(bytes(payloads[i]))
        if msg.unit != unit or msg.command != code:
            raise ValueError(f"sample {i} is from {msg.unit!r} 0x{msg.command:02X}, "
                             f"not {unit!r} 0x{code:02X}")
        for col in HEADER:
            recs[col][i] = getattr(msg, col)
        for q in lay.quantities:
            values = getattr(msg, q)
            if len(values) == elements(q):
                recs[q][i] = values
            elif recs[q].dtype.kind == "f":
                recs[q][i] = np.nan
    return _columns(lay, recs)


def _bulk_rows(lay: Layout, payloads: Sequence[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Which ``payloads`` have the bulk layout ``lay``, and those read as one record array.

    The layout is judged by length and constant bytes.
    """
    size = lay.size
    fits = np.fromiter((len(p) == size for p in payloads), bool, len(payloads))
    raw = np.frombuffer(b"".join(p for p, ok in zip(payloads, fits, strict=True) if ok),
                        np.uint8).reshape(-1, size)
    good = _constant_bytes_hold(lay, raw)
    return np.flatnonzero(fits)[good], raw[good].reshape(-1).view(lay.dtype)


def _constant_bytes_hold(lay: Layout, raw: np.ndarray) -> np.ndarray:
    """Per row of message bytes: whether its tags, lengths, unit and command are ``lay``'s."""
    return np.asarray((raw[:, lay.const_mask]
                       == lay.template.view(np.uint8)[lay.const_mask]).all(axis=1))


def _columns(lay: Layout, recs: np.ndarray) -> dict[str, np.ndarray]:
    n = len(recs)
    columns = {name: np.ascontiguousarray(recs[name]) for name in HEADER}
    for q in lay.quantities:
        columns[q] = np.ascontiguousarray(recs[q]).reshape(n, *QUANTITIES[q].shape)
    return columns
