"""Line faults on demand: what cables, USB hosts and wrong baud rates do to a byte stream."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FaultConfig:
    """Line faults of one unit: rates are per byte, intervals mean seconds between events.

    Attributes:
        bit_flip_rate: Chance that a byte has one bit flipped.
        drop_rate: Chance that a byte is lost.
        stall_every_s: Mean seconds between stalls (the host receives nothing, then
            everything at once); 0: never.
        stall_s: How long a stall lasts.
        disconnect_every_s: Mean seconds between disconnects (the cable is out, bytes
            are lost); 0: never.
        disconnect_s: How long a disconnect lasts.
        disconnect_power_cycles: A disconnect also cuts a USB-powered unit's power, so
            it boots when plugged back in.
    """

    bit_flip_rate: float = 0.0
    drop_rate: float = 0.0
    stall_every_s: float = 0.0
    stall_s: float = 0.05
    disconnect_every_s: float = 0.0
    disconnect_s: float = 1.0
    disconnect_power_cycles: bool = False


class _Episodes:
    """Episodes ``length`` seconds long, starting at random intervals of mean ``every``."""

    def __init__(self, rng: np.random.Generator, every: float, length: float, now: float) -> None:
        self.rng, self.every, self.length = rng, every, length
        self.ended = 0
        self._window = self._next(now)

    def _next(self, now: float) -> tuple[float, float] | None:
        if self.every <= 0:
            return None
        start = now + float(self.rng.exponential(self.every))
        return start, start + self.length

    def active(self, now: float) -> bool:
        if self._window is None or now < self._window[0]:
            return False
        if now < self._window[1]:
            return True
        self.ended += 1
        self._window = self._next(now)
        return False


class Faults:
    """Seeded fault injector for one unit's output.

    Each kind of fault draws from its own generator, and byte faults from one number
    per byte, so the same seed and the same bytes give the same faults however the
    bytes are split into writes.
    """

    def __init__(self, config: FaultConfig, seed: int, now: float) -> None:
        self.config = config
        self._flips, self._drops, stalls, outages = (
            np.random.default_rng([seed, 0xFA017, kind]) for kind in range(4))
        self.bits_flipped = 0
        self.bytes_dropped = 0
        self._stalls = _Episodes(stalls, config.stall_every_s, config.stall_s, now)
        self._outages = _Episodes(outages, config.disconnect_every_s, config.disconnect_s, now)

    @property
    def stalls(self) -> int:
        """Stalls that have ended so far."""
        return self._stalls.ended

    @property
    def disconnects(self) -> int:
        """Disconnects that have ended so far."""
        return self._outages.ended

    def corrupt(self, data: bytes) -> bytes:
        """Flip one bit in, or drop, each byte with the configured probabilities."""
        c = self.config
        if not data or not (c.bit_flip_rate or c.drop_rate):
            return data
        arr = np.frombuffer(data, np.uint8).copy()
        draw = self._flips.random(len(arr))
        flip = draw < c.bit_flip_rate
        if flip.any():
            bit = (draw[flip] / c.bit_flip_rate * 8).astype(np.uint8)  # uniform in 0..7
            arr[flip] ^= (np.uint8(1) << bit).astype(np.uint8)
            self.bits_flipped += int(flip.sum())
        keep = self._drops.random(len(arr)) >= c.drop_rate
        self.bytes_dropped += int((~keep).sum())
        return arr[keep].tobytes()

    def stalled(self, now: float) -> bool:
        """Inside a USB snub: the host receives nothing, then everything at once."""
        return self._stalls.active(now)

    def outage(self, now: float) -> bool:
        """Inside a disconnect: the cable is out and bytes are lost."""
        return self._outages.active(now)


def reframe(data: bytes, sent_baud: int, read_baud: int) -> bytes:
    """What a UART reading at ``read_baud`` makes of bytes sent back to back at ``sent_baud``.

    Each byte is a start bit, eight data bits LSB first and a stop bit; the line is
    idle (high) before and after. The receiver starts a byte on a falling edge,
    samples the middle of each of its own bit periods and keeps the byte even on a
    framing error, as a tty does by default. It then waits for the line to be high
    again before the next falling edge, so a long low line (a break) gives one 0x00.

    Every possible start is a falling edge, and where a byte starting on one edge
    lets the receiver look for the next is known in advance; following that chain
    costs one step per byte received, so the whole is O(n) at any ratio of rates.
    """
    if sent_baud == read_baud or not data:
        return data
    ratio = sent_baud / read_baud  # one received bit, in sent bits
    bits = np.unpackbits(np.frombuffer(data, np.uint8)[:, None], axis=1, bitorder="little")
    frames = np.concatenate([np.zeros((len(data), 1), np.uint8), bits,
                             np.ones((len(data), 1), np.uint8)], axis=1).ravel()
    line = np.concatenate([frames, np.ones(math.ceil(10 * ratio) + 2, np.uint8)])
    size = len(line)
    index = np.arange(size)
    falling = (line == 0) & np.concatenate([[True], line[:-1] == 1])
    edges = np.flatnonzero(falling)
    # first high at or after each bit, and first falling edge at or after it (size: none)
    next_high = np.minimum.accumulate(np.where(line == 1, index, size)[::-1])[::-1]
    next_edge = np.append(np.minimum.accumulate(np.where(falling, index, size)[::-1])[::-1], size)
    stop = np.minimum((edges + 9.5 * ratio).astype(np.int64), size - 1)
    following = np.full(size + 1, size, np.int64)
    following[edges] = next_edge[next_high[stop] + 1]
    chain = following.tolist()
    starts = []
    start = int(edges[0])
    while start < size:
        starts.append(start)
        start = chain[start]
    samples = np.array(starts)[:, None] + (np.arange(1, 9) + 0.5) * ratio
    received = line[samples.astype(np.int64)]
    return np.packbits(received, axis=1, bitorder="little").tobytes()
