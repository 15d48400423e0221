"""How a USB virtual COM port hands a unit's bytes to the host.

The host controller polls the device once per 1 ms frame on the HOST's clock, so
bytes the unit finished at time t reach the driver at the first frame boundary at
or after t. The reading thread then wakes after an exponential OS latency and
reads everything the driver holds by then; now and then the host ignores the
port for 5-40 ms (a stall) and the next read returns the whole backlog at once.
Latency only ever delays: nothing is read before the frame that carried it.

``UsbLink`` is driven by explicit host times, so it serves virtual-time captures
and a live transport alike: ``push`` what the unit finished by a time, then ask
``reads(now)`` for the reads that completed by ``now``. Deterministic from its seed.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from bridge.sim.unit import STEP_SLACK


@dataclass(frozen=True)
class UsbDelivery:
    """The host side of one port: frame grid, OS latency and stalls (seconds)."""

    frame_s: float = 0.001
    frame_phase_s: float = 0.0
    os_latency_mean_s: float = 0.0003
    stall_every_s: float = 20.0
    stall_min_s: float = 0.005
    stall_max_s: float = 0.040
    seed: int = 0

    def __post_init__(self) -> None:
        if self.frame_s <= 0 or self.os_latency_mean_s < 0 or self.stall_every_s < 0:
            raise ValueError("USB delivery: frame_s must be positive, latency and stall "
                             "interval non-negative (stall_every_s=0 means no stalls)")
        if not 0 <= self.stall_min_s <= self.stall_max_s:
            raise ValueError("USB delivery: need 0 <= stall_min_s <= stall_max_s")


class UsbLink:
    """Bytes in at the times the unit finished them; reads out at host times."""

    def __init__(self, config: UsbDelivery, start: float = 0.0) -> None:
        self.config = config
        self._latency = np.random.default_rng([config.seed, 1])
        self._stalls = np.random.default_rng([config.seed, 2])
        self._pending: deque[tuple[float, bytes]] = deque()
        self._wake: float | None = None
        self._stall = (start, start)
        self._next_stall(start)
        self.stalls = 0

    def frame_at(self, t: float) -> float:
        """The first frame boundary at or after host time ``t``."""
        c = self.config
        k = math.ceil((t - c.frame_phase_s) / c.frame_s - STEP_SLACK)
        return c.frame_phase_s + k * c.frame_s

    def push(self, data: bytes, finished: float) -> None:
        """Bytes the unit had finished sending by host time ``finished``."""
        if data:
            self._pending.append((self.frame_at(finished), data))

    def reads(self, now: float) -> list[tuple[float, bytes]]:
        """Every read that completed by ``now``: (host time of the read, bytes)."""
        out: list[tuple[float, bytes]] = []
        while self._pending:
            if self._wake is None:
                latency = float(self._latency.exponential(self.config.os_latency_mean_s)) \
                    if self.config.os_latency_mean_s else 0.0
                self._wake = self._unstalled(self._pending[0][0] + latency)
            if self._wake > now:
                break
            chunks = []
            while self._pending and self._pending[0][0] <= self._wake:
                chunks.append(self._pending.popleft()[1])
            out.append((self._wake, b"".join(chunks)))
            self._wake = None
        return out

    def _next_stall(self, after: float) -> None:
        c = self.config
        if not c.stall_every_s:
            self._stall = (math.inf, math.inf)
            return
        begin = after + float(self._stalls.exponential(c.stall_every_s))
        self._stall = (begin, begin + float(self._stalls.uniform(c.stall_min_s, c.stall_max_s)))

    def _unstalled(self, t: float) -> float:
        """A read due during a stall happens when the stall ends."""
        while self._stall[1] <= t:
            self._next_stall(self._stall[1])
        if self._stall[0] <= t:
            self.stalls += 1
            return self._stall[1]
        return t
