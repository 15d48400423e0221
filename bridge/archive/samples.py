"""GX3's part of reading an archive: its ImuSamples decoded in bulk, straight out of the chunks.

Each chunk's messages are grouped by unit and command with array operations; a group
whose messages all have the bulk layout's size reaches the decoder as rows read straight
out of the chunks, any other as one bytes object per message.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from bridge.archive.records import Block, ChannelInfo, rows
from bridge.bus.codec import HEADERS, decode_batch, layout, parse, peek

#: Hears messages left out: (topic, how many, why in words that follow "skipped N").
Skip = Callable[[str, int, str], None]


@dataclass
class ArchivedSamples:
    """Decoded ImuSamples of one unit and record type, in sample-time order.

    ``columns`` are those of bridge.bus.codec.decode_batch (command, timer, ticks,
    time_ns, rx_ns and each quantity shaped as in the command table); ``receive_ns`` is
    when the recorder received each sample.
    """

    unit: str
    code: int
    columns: dict[str, np.ndarray]
    receive_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.receive_ns)


def decode_samples(blocks: Iterable[Block], channels: Iterable[ChannelInfo],
                   units: list[str], codes: Iterable[int] | None, skip: Skip
                   ) -> list[ArchivedSamples]:
    """ImuSamples decoded in bulk, one ``ArchivedSamples`` per unit and record type.

    Messages that are not samples of their unit are left out, and told to ``skip``.

    Args:
        blocks: The chunks' messages.
        channels: The archive's channels.
        units: The units to decode, sorted.
        codes: Only these record types (command bytes); None: every type.
        skip: Hears the messages left out.

    Returns:
        Sample columns, by unit and then record type.
    """
    channels = list(channels)
    wanted_codes = None if codes is None else set(codes)
    unit_of = np.full(1 << 16, -1, np.int64)  # channel id -> index in units
    for c in channels:
        if c.kind == "imu" and c.unit in units:
            unit_of[c.id] = units.index(c.unit)
    groups: dict[tuple[str, int], list[tuple[Block, np.ndarray]]] = {}
    for block in blocks:
        which = unit_of[block.channel]
        for k in np.unique(which[which >= 0]).tolist():
            picked = np.flatnonzero(which == k)
            commands = _commands(block, picked, units[k])
            for code in np.unique(commands).tolist():
                if wanted_codes is None or code in wanted_codes:
                    groups.setdefault((units[k], code), []).append(
                        (block, picked[commands == code]))
    out: list[ArchivedSamples] = []
    for (unit, code), parts in sorted(groups.items(), key=lambda g: g[0]):
        topic = next((c.topic for c in channels if c.unit == unit and c.kind == "imu"),
                     f"{unit}/imu")
        try:
            layout(code, unit)
        except ValueError:
            skip(topic, sum(len(p) for _, p in parts), "that are not ImuSamples "
                 "of a known record type")
            continue
        try:
            cols = _decode(unit, code, parts)
        except ValueError:  # a message that is not this unit's, or corrupt: leave it out
            kept = [(b, p[_decodable(unit, code, b, p)]) for b, p in parts]
            bad = sum(len(p) for _, p in parts) - sum(len(p) for _, p in kept)
            skip(topic, bad, f"that do not decode as {unit}'s 0x{code:02X} samples "
                 "(another unit's name, or corrupt)")
            parts = [(b, p) for b, p in kept if len(p)]
            if not parts:
                continue
            cols = _decode(unit, code, parts)
        log_time = np.concatenate([b.log_time[p] for b, p in parts])
        received = np.concatenate([b.publish_time[p] for b, p in parts])
        if len(log_time) > 1 and (log_time[1:] < log_time[:-1]).any():  # else as they are
            order = np.argsort(log_time, kind="stable")
            cols, received = {k: v[order] for k, v in cols.items()}, received[order]
        out.append(ArchivedSamples(unit, code, cols, received))
    return out


def _commands(block: Block, picked: np.ndarray, unit: str) -> np.ndarray:
    """Command bytes of the ImuSamples at indexes ``picked``.

    Read at their fixed place in the bulk layout (tags checked), parsed for messages
    in any other layout.
    """
    n = len(unit.encode())
    start, length = block.start[picked], block.length[picked]
    buf = np.frombuffer(block.data, np.uint8)
    fits = length >= n + 7
    long_enough = np.flatnonzero(fits)
    at = start[long_enough]
    fits[long_enough] = (buf[at] == 0x0A) & (buf[at + 1] == n) & (buf[at + 2 + n] == 0x15)
    out = np.zeros(len(start), np.int64)
    out[long_enough] = rows(buf, at + 3 + n, 4).copy().view("<u4")[:, 0]
    for i in np.flatnonzero(~fits).tolist():
        s = int(start[i])
        try:
            out[i] = peek(block.data[s : s + int(length[i])])[1]
        except ValueError:
            out[i] = -1  # not an ImuSample: left out, and counted, by ``decode_samples``
    return out


def _decode(unit: str, code: int, parts: list[tuple[Block, np.ndarray]]
            ) -> dict[str, np.ndarray]:
    """decode_batch of the messages ``parts`` pick out of their chunks.

    Rows read straight out of the chunks when all have the size of one bulk layout (an
    older bridge's too), else a bytes object each.
    """
    found: np.ndarray | list[bytes] | None = None
    for header in HEADERS:
        size = layout(code, unit, header).size
        if all((b.length[p] == size).all() for b, p in parts):
            found = np.concatenate([b.rows(p, size) for b, p in parts])
            break
    if found is None:
        found = [payload for b, p in parts for payload in b.payloads(p)]
    return decode_batch(unit, code, found)


def _decodable(unit: str, code: int, block: Block, picked: np.ndarray) -> np.ndarray:
    """Which of the messages at ``picked`` decode as ``unit``'s samples of ``code``.

    The bulk layout's fixed bytes are checked at once, any other message parsed on its own.
    """
    lay = layout(code, unit)
    ok = np.zeros(len(picked), bool)
    sized = np.flatnonzero(block.length[picked] == lay.size)
    if len(sized):
        fixed = block.rows(picked[sized], lay.size)
        ok[sized] = (fixed[:, lay.const_mask] == lay.template.view(np.uint8)[lay.const_mask]
                     ).all(axis=1)
    for i in np.flatnonzero(~ok).tolist():
        try:
            msg = parse(block.payloads(picked[i : i + 1])[0])
        except ValueError:
            continue
        ok[i] = msg.unit == unit and msg.command == code
    return ok
