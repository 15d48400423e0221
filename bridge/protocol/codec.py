"""Encode commands and replies, decode replies, all from the command table.

Replies are handled columnar: a block of n records of one type is one NumPy
structured view, so decoding costs a handful of array operations, not one
Python object per record. Floats follow the 0xDB little-endian flag; the timer,
the other integers and the checksum are always big-endian.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bridge.exceptions import ProtocolError
from bridge.protocol.table import (
    COMMANDS,
    REPLIES,
    Command,
    Field,
    lookup,
)


def checksum(data: bytes | bytearray | memoryview) -> int:
    """The manual's checksum: the 16-bit wrapping sum of every byte.

    Args:
        data: The bytes summed: a reply without its last two bytes, which carry the sum.

    Returns:
        The sum, 0 to 65535.
    """
    return sum(data) & 0xFFFF


def checksum_rows(block: np.ndarray) -> np.ndarray:
    """``checksum`` of each row of an (n, k) uint8 block, at array speed.

    Args:
        block: The rows summed.

    Returns:
        The (n,) sums.
    """
    sums: np.ndarray = block.sum(axis=1, dtype=np.uint32)
    return sums & 0xFFFF


def _wire_dtype(f: Field, little_endian: bool) -> str:
    if f.kind == "f32":
        return "<f4" if little_endian else ">f4"
    if f.kind == "ascii":
        return "S16"
    return {"u8": "u1", "u16": ">u2", "u32": ">u4"}[f.kind]


def _parts(fields: tuple[Field, ...], little_endian: bool) -> list[tuple[Any, ...]]:
    """Packed dtype entries of message fields in wire order (reserved bytes as voids)."""
    parts: list[tuple[Any, ...]] = []
    for i, f in enumerate(fields):
        if f.is_pad:
            parts.append((f"_pad{i}", f"V{f.count}"))
        else:
            parts.append((f.name, _wire_dtype(f, little_endian), f.shape))
    return parts


@functools.cache
def reply_dtype(code: int, little_endian: bool = False) -> np.dtype[Any]:
    """The packed wire layout of one reply: echo byte, fields, checksum.

    Args:
        code: The reply's first byte (``REPLIES``).
        little_endian: The float byte order (0xDB flag bit 4); integers are big-endian.

    Returns:
        A structured dtype of the reply's length: ``code``, each field by name (reserved
        bytes as ``_padN`` voids), ``checksum``.
    """
    spec = REPLIES[code]
    dtype = np.dtype([("code", "u1"), *_parts(spec.fields, little_endian),
                      ("checksum", ">u2")])
    assert dtype.itemsize == spec.length
    return dtype


@functools.cache
def _command_dtype(code: int) -> np.dtype[Any]:
    cmd = COMMANDS[code]
    parts: list[tuple[Any, ...]] = [("code", "u1")]
    if cmd.confirm:
        parts.append(("confirm", "V" + str(len(cmd.confirm))))
    return np.dtype(parts + _parts(cmd.params, False))


def _native(f: Field) -> str:
    return {"f32": "f4", "u8": "u1", "u16": "u2", "u32": "u4", "ascii": "S16"}[f.kind]


def _check_value(cmd: Command, f: Field, value: Any) -> None:
    """Reject what the unit would clamp or ignore, naming the allowed values."""
    where = f"0x{cmd.code:02X} {cmd.name}: {f.name}"
    if f.kind == "f32":
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != f.shape:
            raise ProtocolError(f"{where} needs {f.count} numbers, got {arr.shape}")
        return
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ProtocolError(f"{where} must be an integer, got {value!r}")
    bits = {"u8": 8, "u16": 16, "u32": 32}[f.kind]
    if not 0 <= value < 1 << bits:
        raise ProtocolError(f"{where}={value} does not fit {bits} bits")
    if f.allowed is not None and value not in f.allowed:
        shown = ", ".join(str(v) for v in sorted(f.allowed))
        raise ProtocolError(f"{where}={value} is not one of {shown}")
    if (f.lo is not None and value < f.lo) or (f.hi is not None and value > f.hi):
        raise ProtocolError(f"{where}={value} is outside {f.lo:g}..{f.hi:g}")


def encode_command(command: int | str, /, strict: bool = True, **params: Any) -> bytes:
    """The bytes that send ``command`` with ``params``, confirmation sequence included.

    Args:
        command: The command's code or name; positional-only so that 0xC4's parameter,
            also named ``command``, can be passed as a keyword.
        strict: Reject values the unit would clamp or ignore; False only requires each
            value to fit its field (for probing a unit's range rules).
        **params: The command's parameters by name. Those the unit ignores (a read's,
            such as 0xDB function 0) may be left out; they are sent as 0.

    Returns:
        The command's bytes, as the host sends them.

    Raises:
        KeyError: No such command.
        ProtocolError: A parameter is missing, unknown or out of range, or the command
            has no documented layout (0xFD); the message says which.
    """
    cmd = lookup(command)
    if not cmd.documented:
        raise ProtocolError(f"0x{cmd.code:02X} {cmd.name}: the manual gives no byte layout; "
                            "use the vendor's tool for this")
    names = [f.name for f in cmd.params if not f.is_pad]
    ignored = cmd.ignores(params)
    unknown = set(params) - set(names)
    missing = [n for n in names if n not in params and n not in ignored]
    if unknown or missing:
        raise ProtocolError(f"0x{cmd.code:02X} {cmd.name} takes "
                            f"{', '.join(names) or 'no parameters'}"
                            + (f"; missing {', '.join(missing)}" if missing else "")
                            + (f"; unknown {', '.join(sorted(unknown))}" if unknown else ""))
    rec = np.zeros(1, _command_dtype(cmd.code))
    rec["code"] = cmd.code
    if cmd.confirm:
        rec["confirm"] = np.void(cmd.confirm)
    for f in cmd.params:
        if f.is_pad:
            continue
        value = params.get(f.name, 0)
        if strict and f.name not in ignored:
            _check_value(cmd, f, value)
        elif f.kind != "f32":
            _check_value(cmd, Field(f.name, f.kind), value)
        rec[f.name] = value
    return rec.tobytes()


@dataclass(frozen=True)
class ParsedCommand:
    """A command as a unit receives it."""

    command: Command
    params: dict[str, Any]
    confirmed: bool


def command_length(code: int) -> int | None:
    """Bytes a command starting with ``code`` occupies, as the unit reads them.

    Args:
        code: The first byte.

    Returns:
        The command's length, or None for a byte the unit ignores.
    """
    cmd = COMMANDS.get(code)
    return cmd.length if cmd is not None else None


def parse_command(data: bytes) -> ParsedCommand:
    """Decode one whole command as the unit sees it.

    Args:
        data: The command's ``command_length`` bytes, its code first.

    Returns:
        The command, its parameters as plain Python values, and whether its
        confirmation bytes were right.

    Raises:
        KeyError: The first byte is no command.
        ProtocolError: ``data`` is not the command's length.
    """
    cmd = COMMANDS[data[0]]
    if len(data) != cmd.length:
        raise ProtocolError(f"0x{cmd.code:02X} {cmd.name} is {cmd.length} bytes, got {len(data)}")
    confirmed = data[1 : 1 + len(cmd.confirm)] == cmd.confirm
    rec = np.frombuffer(data, _command_dtype(cmd.code))[0]
    params = {f.name: _py(rec[f.name]) for f in cmd.params if not f.is_pad}
    return ParsedCommand(cmd, params, confirmed)


def _py(value: Any) -> Any:
    """A NumPy scalar or array as plain Python (lists, floats, ints, str)."""
    if isinstance(value, bytes):
        return value.decode("ascii", "replace").rstrip("\x00 ")
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value.item() if isinstance(value, np.generic) else value


def encode_replies(
    code: int, columns: Mapping[str, Any], n: int = 1, little_endian: bool = False
) -> bytes:
    """N replies of one type from per-field columns, checksums included.

    Args:
        code: The replies' first byte (``REPLIES``).
        columns: Each field's values by name, n of them (or one, broadcast to n); an
            ``ascii`` field may be a str.
        n: How many replies.
        little_endian: The float byte order.

    Returns:
        The replies end to end.
    """
    spec = REPLIES[code]
    dtype = reply_dtype(code, little_endian)
    recs = np.zeros(n, dtype)
    recs["code"] = code
    for f in spec.fields:
        if f.is_pad:
            continue
        value = columns[f.name]
        if f.kind == "ascii":
            value = value.encode("ascii").ljust(16)[:16] if isinstance(value, str) else value
        recs[f.name] = value
    raw = recs.view(np.uint8).reshape(n, spec.length)
    recs["checksum"] = checksum_rows(raw[:, :-2])
    return recs.tobytes()


def encode_reply(code: int, little_endian: bool = False, **values: Any) -> bytes:
    """One reply; the emulator's and the tests' way to build exact reply bytes.

    Args:
        code: The reply's first byte (``REPLIES``).
        little_endian: The float byte order.
        **values: Each field's value by name.

    Returns:
        The reply, checksum included.
    """
    return encode_replies(code, values, 1, little_endian)


@functools.cache
def _decoded_fields(code: int) -> tuple[tuple[str, str], ...]:
    """(name, native dtype) of each decoded field of a reply."""
    return tuple((f.name, _native(f)) for f in REPLIES[code].fields if not f.is_pad)


def decode_block(code: int, block: np.ndarray, little_endian: bool = False) -> dict[str, Any]:
    """Columns of a block of replies of one type, in native types.

    Args:
        code: The replies' first byte (``REPLIES``).
        block: The replies' bytes, (n, length) uint8.
        little_endian: The float byte order they were sent in.

    Returns:
        One array per field by name, n rows each (vectors and matrices shaped as in the
        command table).
    """
    return dict(_Columns(code, block, little_endian))


class _Columns(Mapping[str, np.ndarray]):
    """The fields of an (n, length) uint8 block of replies, each decoded when first asked for.

    A live bridge reads only the timer of each record and publishes the rest from the
    wire bytes, and per read NumPy's cost per call is what counts.
    """

    def __init__(self, code: int, block: np.ndarray, little_endian: bool = False) -> None:
        self._recs = block.reshape(-1).view(reply_dtype(code, little_endian))
        self._natives = dict(_decoded_fields(code))
        self._done: dict[str, np.ndarray] = {}

    def __getitem__(self, name: str) -> np.ndarray:
        col = self._done.get(name)
        if col is None:
            col = self._done[name] = self._recs[name].astype(self._natives[name])
        return col

    def __iter__(self) -> Iterator[str]:
        return iter(self._natives)

    def __len__(self) -> int:
        return len(self._natives)


@functools.cache
def _domain_checks(code: int, little_endian: bool) -> tuple[tuple[struct.Struct, int, Field], ...]:
    """(unpacker, byte offset, field) for each field of a reply that has a domain.

    Adjacent fields of one kind and domain share one unpacker (named by the first), so a
    data record's vectors cost one call per bound rather than one per field.
    """
    checks: list[tuple[str, int, Field]] = []
    offset = 1
    end = 0
    for f in REPLIES[code].fields:
        if f.domain is not None or f.domain_values is not None:
            order = "<" if f.kind == "f32" and little_endian else ">"
            fmt = {"f32": "f", "u8": "B", "u16": "H", "u32": "I"}[f.kind]
            last = checks[-1][2] if checks else None
            if (last is not None and end == offset and f.domain_values is None
                    and (last.kind, last.domain, last.domain_values) == (f.kind, f.domain, None)):
                checks[-1] = (checks[-1][0] + str(f.count) + fmt, checks[-1][1], last)
            else:
                checks.append((order + str(f.count) + fmt, offset, f))
            end = offset + f.size
        offset += f.size
    return tuple((struct.Struct(fmt), at, f) for fmt, at, f in checks)


@functools.cache
def native_checks(code: int, little_endian: bool) -> bytes:
    """``plausible``'s checks of a reply as the compiled core reads them (``bridge/_records.c``).

    Args:
        code: The reply's first byte.
        little_endian: The float byte order.

    Returns:
        Per check, as native float64s: its offset, value count, value width, whether
        floats, whether little-endian, its bounds (infinite when it has none), and its
        allowed values after their count.
    """
    out: list[float] = []
    for unpacker, offset, f in _domain_checks(code, little_endian):
        count = len(unpacker.unpack_from(bytes(unpacker.size)))
        lo, hi = f.domain if f.domain is not None else (-math.inf, math.inf)
        values = sorted(f.domain_values or ())
        out += [offset, count, unpacker.size // count, f.kind == "f32",
                unpacker.format[0] == "<", lo, hi, len(values), *values]
    return struct.pack(f"={len(out)}d", *out)


def plausible(code: int, record: bytes, little_endian: bool = False) -> bool:
    """Whether every field of one reply holds a value a unit can send.

    A 16-bit additive checksum matches misaligned or damaged bytes now and then
    (short replies especially), so the framer requires this of every record.
    NaN and infinities pass in every float field: a unit sends them.

    Args:
        code: The reply's first byte.
        record: The reply's bytes.
        little_endian: The float byte order.

    Returns:
        False if any field is outside its ``domain`` or ``domain_values``.
    """
    for unpacker, offset, f in _domain_checks(code, little_endian):
        values = unpacker.unpack_from(record, offset)
        if f.domain is not None and f.domain_values is None \
                and f.domain[0] <= min(values) and max(values) <= f.domain[1]:
            continue  # the usual case, decided in C (NaN, inf: looked at below)
        for v in values:
            outside = f.domain is not None and not f.domain[0] <= v <= f.domain[1]
            if outside and (f.kind != "f32" or math.isfinite(v)):
                return False
            if f.domain_values is not None and v not in f.domain_values:
                return False
    return True


@functools.cache
def _row_checks(
    code: int, little_endian: bool
) -> tuple[list[tuple[int, int, np.ndarray]], list[tuple[int, int, np.dtype[Any], Field]]]:
    """``_domain_checks`` grouped for blocks: adjacent float fields form one run.

    A data record then costs one conversion and a few comparisons rather than per field.
    """
    runs: list[tuple[int, int, list[float]]] = []  # offset, size, bound per element
    ints: list[tuple[int, int, np.dtype[Any], Field]] = []
    for unpacker, offset, f in _domain_checks(code, little_endian):
        if f.kind != "f32":
            ints.append((offset, unpacker.size, np.dtype(_wire_dtype(f, little_endian)), f))
            continue
        assert f.domain is not None and f.domain[0] == -f.domain[1], "float domains are ±bound"
        if not runs or runs[-1][0] + runs[-1][1] != offset:
            runs.append((offset, 0, []))
        start, size, bounds = runs[-1]
        runs[-1] = (start, size + unpacker.size, bounds + [f.domain[1]] * (unpacker.size // 4))
    return [(o, n, np.array(b)) for o, n, b in runs], ints


def plausible_rows(code: int, block: np.ndarray, little_endian: bool = False) -> np.ndarray:
    """``plausible`` of each row of an (n, length) uint8 block, at array speed.

    Args:
        code: The replies' first byte.
        block: The replies' bytes, one a row.
        little_endian: The float byte order.

    Returns:
        (n,) bool, True where the row is plausible.
    """
    ok = np.ones(len(block), bool)
    floats, ints = _row_checks(code, little_endian)
    wire = np.dtype("<f4" if little_endian else ">f4")
    for offset, size, bound in floats:
        with np.errstate(invalid="ignore"):  # garbage holds signalling NaNs
            x = np.abs(block[:, offset : offset + size].view(wire).astype(np.float64))
        ok &= ~((x > bound) & (x != np.inf)).any(axis=1)  # NaN compares false: allowed
    for offset, size, dtype, f in ints:
        col = block[:, offset : offset + size].view(dtype)
        if f.domain is not None:
            ok &= ((col >= f.domain[0]) & (col <= f.domain[1])).all(axis=1)
        if f.domain_values is not None:
            ok &= np.isin(col, sorted(f.domain_values)).all(axis=1)
    return ok


@dataclass
class Batch:
    """n consecutive replies of one type and float byte order: one array per field.

    ``offsets`` are the byte positions of each record's first byte in the stream the
    framer was fed; ``rx_ns`` the receive time of the read that completed each record
    (its last byte), so a replayed capture times every record as the live run did.
    ``little_endian`` is the float byte order the records were decoded with; ``block``
    the records' wire bytes, (n, length) uint8, when they came from a byte stream.
    ``part_ns`` and ``part_bytes``: for a record whose bytes came in more than one read,
    or right after a read that ended where it begins, the receive time of the latest read
    before the completing one and how many of the record's bytes had arrived by then (0
    to its length less one; None: no record here had such a read; see ``partial``). Such
    a read says when the record was on its way, and when it was not yet: the timing
    layer bounds the record's instant from both sides with it. ``batch["accel"]`` is
    ``batch.columns["accel"]``; ``len(batch)`` the record count.
    """

    code: int
    columns: Mapping[str, np.ndarray]
    offsets: np.ndarray
    rx_ns: np.ndarray
    little_endian: bool
    block: np.ndarray | None = None
    part_ns: np.ndarray | None = None
    part_bytes: np.ndarray | None = None

    @classmethod
    def from_block(cls, code: int, block: np.ndarray, offsets: np.ndarray, rx_ns: np.ndarray,
                   little_endian: bool, part_ns: np.ndarray | None = None,
                   part_bytes: np.ndarray | None = None) -> Batch:
        """Records as they came off the wire, decoded only as far as they are read.

        Args:
            code: The records' first byte.
            block: Their wire bytes, (n, length) uint8.
            offsets: Each record's stream position.
            rx_ns: The receive time of the read that completed each.
            little_endian: The float byte order.
            part_ns: The receive time of each record's partial read (see the class).
            part_bytes: The record's bytes that partial read had brought.

        Returns:
            The batch, its ``block`` set.
        """
        return cls(code, _Columns(code, block, little_endian), offsets, rx_ns, little_endian,
                   block, part_ns, part_bytes)

    def partial(self) -> tuple[np.ndarray, np.ndarray]:
        """Per record, a receive time and how many of its bytes had arrived by then.

        Returns:
            The latest read that ended inside each record, or right where it begins, and
            the record's bytes it had brought (0 for the latter), else the read that
            completed it and the record's length.
        """
        if self.part_ns is None or self.part_bytes is None:
            return self.rx_ns, np.full(len(self.rx_ns), REPLIES[self.code].length, np.int64)
        return self.part_ns, self.part_bytes

    @classmethod
    def concatenate(cls, batches: Sequence[Batch]) -> Batch:
        """Consecutive batches of one record type and byte order as one.

        Args:
            batches: At least one batch, in stream order.

        Returns:
            One batch of all their records, still wire bytes when they all are.
        """
        first = batches[0]
        if len(batches) == 1:
            return first
        offsets = np.concatenate([b.offsets for b in batches])
        rx_ns = np.concatenate([b.rx_ns for b in batches])
        part_ns = part_bytes = None
        if any(b.part_ns is not None for b in batches):
            parts = [b.partial() for b in batches]
            part_ns = np.concatenate([p[0] for p in parts])
            part_bytes = np.concatenate([p[1] for p in parts])
        blocks = [b.block for b in batches if b.block is not None]
        if len(blocks) == len(batches):
            return cls.from_block(first.code, np.concatenate(blocks), offsets, rx_ns,
                                  first.little_endian, part_ns, part_bytes)
        columns = {k: np.concatenate([b.columns[k] for b in batches]) for k in first.columns}
        return cls(first.code, columns, offsets, rx_ns, first.little_endian,
                   part_ns=part_ns, part_bytes=part_bytes)

    def select(self, keep: np.ndarray) -> Batch:
        """The records where ``keep`` is True.

        Args:
            keep: (n,) bool, one per record.

        Returns:
            A batch of those records.
        """
        part_ns = None if self.part_ns is None else self.part_ns[keep]
        part_bytes = None if self.part_bytes is None else self.part_bytes[keep]
        if self.block is not None:
            return Batch.from_block(self.code, self.block[keep], self.offsets[keep],
                                    self.rx_ns[keep], self.little_endian, part_ns, part_bytes)
        return Batch(self.code, {k: v[keep] for k, v in self.columns.items()},
                     self.offsets[keep], self.rx_ns[keep], self.little_endian,
                     part_ns=part_ns, part_bytes=part_bytes)

    def __len__(self) -> int:
        return len(self.offsets)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def records(self) -> Iterator[dict[str, Any]]:
        """One plain dict per record, for small tools.

        Yields:
            The record's ``command``, then its fields, as plain Python values.
        """
        for i in range(len(self)):
            out: dict[str, Any] = {"command": self.code}
            for name, col in self.columns.items():
                out[name] = _py(col[i])
            yield out


@dataclass
class Records:
    """``Batch`` for a live read's record or two, in plain Python.

    Each record's wire bytes and stream position, the receive time of the read that
    completed it. Array set-up costs more than such a read's work; ``batch`` gives the
    very ``Batch``.
    """

    code: int
    little_endian: bool
    wire: list[bytes]
    offsets: list[int]
    rx_ns: list[int]
    part_ns: list[int] | None = None  # as ``Batch``'s
    part_bytes: list[int] | None = None

    def __len__(self) -> int:
        return len(self.wire)

    def timers(self) -> list[int]:
        """The unit's timer of each record (big-endian, whatever the float byte order).

        Returns:
            One timer (uint32) per record.
        """
        at = _timer_at(self.code)
        return [int.from_bytes(w[at : at + 4], "big") for w in self.wire]

    def batch(self) -> Batch:
        """The very ``Batch`` the framer gives for these records.

        Returns:
            The records as arrays, their wire bytes as ``block``.
        """
        block = np.frombuffer(b"".join(self.wire), np.uint8).reshape(len(self.wire), -1)
        parts = (None, None) if self.part_ns is None or self.part_bytes is None else \
            (np.array(self.part_ns, np.int64), np.array(self.part_bytes, np.int64))
        return Batch.from_block(self.code, block, np.array(self.offsets, np.int64),
                                np.array(self.rx_ns, np.int64), self.little_endian, *parts)


@functools.cache
def _timer_at(code: int) -> int:
    return REPLIES[code].offset("timer")
