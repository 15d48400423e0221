"""Sample instants from the raw clock onto the host's realtime clock, each at its own instant.

Each read carries both clocks (``bridge.device.clock.stamp``), so the realtime clock's
offset from the raw clock is known at every read. An instant between two reads gets
the offset there: linear between them, the nearer read's where the clock was stepped
(the offset moved by more than ``STEP_MIN_NS`` and more than ``MAX_SLEW`` of the time
between the reads, which no slew does). Steps, and slews faster than ``SLEW_PPM`` beyond
the clock's usual rate, are named as they are found (``ClockChange``).

``RealtimeTrack`` does this live, a read at a time; ``RealtimeReads`` for a capture's
reads all at once. Both map an instant with the last ``WINDOW`` reads up to the one that
completed its record (``until``), so a capture replays to the very instants published
live. Why the clock model never sees a step or a slew: docs/design/time.md.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, overload

import numpy as np
import numpy.typing as npt

STEP_MIN_NS = 20_000
MAX_SLEW = 0.1
SLEW_PPM = 200.0
SPAN_NS = 250_000_000  # the realtime clock's rate is judged over spans of reads this long
WINDOW = 1024  # reads up to the completing one an instant is mapped with
_BASELINE_PPM = 500.0  # a first span faster than the kernel's frequency range is a slew
_BASELINE_GAIN = 0.125
_LEAP_NS = 1_000_000_000
_DAY_NS = 86_400 * _LEAP_NS
_LEAP_SLACK_NS = 10_000_000


class ChangeKind(StrEnum):
    """How the host's realtime clock was moved."""

    STEP = "step"
    SLEW = "slew"


@dataclass(frozen=True)
class ClockChange:
    """A step or a fast slew of the host's realtime clock against the raw clock.

    ``size_ns``: how far the realtime clock moved (positive: forward); ``real_ns``: when,
    on the realtime clock (a step: just after it, between the reads around it; a slew:
    where it began); ``raw_ns`` the same instant on the raw clock; ``span_ns``: a step's
    time between those reads, a slew's duration.
    """

    kind: ChangeKind
    size_ns: int
    real_ns: int
    raw_ns: int
    span_ns: int

    @property
    def leap(self) -> bool:
        """A step of one second at midnight UTC: a leap second inserted or deleted."""
        if self.kind != ChangeKind.STEP or abs(abs(self.size_ns) - _LEAP_NS) > _LEAP_SLACK_NS:
            return False
        into_day = self.real_ns % _DAY_NS
        return min(into_day, _DAY_NS - into_day) < 2 * _LEAP_NS

    def describe(self) -> str:
        """One line for people.

        Returns:
            What moved the clock (a step, a slew, a leap second), by how much, and over
            what time.
        """
        size = f"{self.size_ns / 1e6:+,.3f} ms"
        if self.kind == ChangeKind.SLEW:
            ppm = self.size_ns / max(1, self.span_ns) * 1e6
            return (f"the host clock slewed {size} over {self.span_ns / 1e9:,.2f} s "
                    f"({ppm:+,.0f} ppm)")
        what = "a leap second: the host clock stepped" if self.leap else \
            "the host clock stepped"
        return f"{what} {size} (between two reads {self.span_ns / 1e6:,.1f} ms apart)"


@overload
def _jumps(change: int, apart: int) -> bool: ...
@overload
def _jumps(change: np.ndarray, apart: np.ndarray) -> np.ndarray: ...
def _jumps(change: Any, apart: Any) -> Any:
    """Whether an offset ``change`` between reads ``apart`` ns apart is a step.

    No slew is that fast. For numbers and for arrays alike.
    """
    size = abs(change)
    return (size > STEP_MIN_NS) & (size > MAX_SLEW * apart)


def _between(t: int, ra: int, oa: int, rb: int, ob: int) -> int:
    """The offset at ``t`` between reads (``ra``, ``oa``) and (``rb``, ``ob``)."""
    if _jumps(ob - oa, rb - ra):
        return oa if t - ra < rb - t else ob
    return oa + round((ob - oa) * ((t - ra) / (rb - ra)))


class _Slews:
    """Slews found from the realtime clock's rate over spans of reads.

    A span whose rate is more than ``SLEW_PPM`` from the usual one is slewed; a run of
    them is one slew, named when it ends, its rate the fastest span's (a slew rarely
    fills its first and last spans) and its start where the first span's share of it
    would begin at that rate. The usual rate (the disciplined frequency) follows the
    other spans.
    """

    def __init__(self) -> None:
        self.baseline: float | None = None  # ns of offset per ns of raw clock
        # the run of slewed spans: where its first span ends (raw, real) and how much of
        # the slew it held, moved in all, the fastest rate
        self._run: tuple[int, int, float, float, float] | None = None

    def span(self, raw0: int, raw1: int, real1: int, moved: int) -> ClockChange | None:
        """One span of reads from ``raw0`` to ``raw1`` (realtime ``real1``).

        Over it the offset moved by ``moved`` besides any steps.
        """
        length = raw1 - raw0
        rate = moved / length
        if self.baseline is None:
            self.baseline = rate if abs(rate) * 1e6 <= _BASELINE_PPM else 0.0
        excess = rate - self.baseline
        if abs(excess) * 1e6 > SLEW_PPM:
            end_raw, end_real, first, total, fastest = self._run or \
                (raw1, real1, excess * length, 0.0, 0.0)
            self._run = (end_raw, end_real, first, total + excess * length,
                         max(fastest, abs(excess)))
            return None
        self.baseline += (rate - self.baseline) * _BASELINE_GAIN
        if self._run is None:
            return None
        end_raw, end_real, first, total, fastest = self._run
        self._run = None
        lead = round(abs(first) / fastest)
        return ClockChange(ChangeKind.SLEW, round(total), end_real - lead, end_raw - lead,
                           round(abs(total) / fastest))


class RealtimeTrack:
    """Live: each read's offset (realtime less raw) as it comes; instants mapped by them."""

    def __init__(self) -> None:
        self._raw: list[int] = []
        self._off: list[int] = []
        self._slews = _Slews()
        self._span: tuple[int, int, int] | None = None  # raw, offset, steps since: its start

    @property
    def offset_ns(self) -> int | None:
        """The realtime clock less the raw clock at the latest read (None before one)."""
        return self._off[-1] if self._off else None

    def add(self, raws: list[int], reals: list[int]) -> list[ClockChange]:
        """The next reads' stamps, in order.

        Args:
            raws: Their receive times on the raw monotonic clock.
            reals: The same instants on the realtime clock.

        Returns:
            The steps and slews they show.
        """
        changes: list[ClockChange] = []
        raw, off = self._raw, self._off
        for r, real in zip(raws, reals, strict=True):
            o = real - r
            if off:
                change = o - off[-1]
                if _jumps(change, r - raw[-1]):
                    changes.append(ClockChange(ChangeKind.STEP, change, real - (r - raw[-1]) // 2,
                                               (r + raw[-1]) // 2, r - raw[-1]))
                    if self._span is not None:
                        self._span = (*self._span[:2], self._span[2] + change)
            raw.append(r)
            off.append(o)
            span = self._span
            if span is None:
                self._span = (r, o, 0)
            elif r - span[0] >= SPAN_NS:
                slew = self._slews.span(span[0], r, real, o - span[1] - span[2])
                if slew is not None:
                    changes.append(slew)
                self._span = (r, o, 0)
        if len(raw) > 4 * WINDOW:
            del raw[: -2 * WINDOW], off[: -2 * WINDOW]
        return changes

    def map(self, instants: list[int], until: list[int]) -> list[int]:
        """Raw-clock instants on the realtime clock.

        Args:
            instants: Raw-clock ns.
            until: Per instant, the raw stamp of the read that completed its record: the
                instant is mapped by the reads up to that one (for that read's own stamp,
                its own realtime stamp).

        Returns:
            Realtime ns; the instants themselves before any read was heard.
        """
        raw, off = self._raw, self._off
        if not raw:  # no read heard: the instants are the caller's own clock's
            return list(instants)
        out: list[int] = []
        hi = len(raw) - 1
        for t, u in zip(instants, until, strict=True):
            if raw[hi] != u:
                hi = max(0, bisect_right(raw, u) - 1)
            if t >= raw[hi]:
                out.append(t + off[hi])
                continue
            lo = max(0, hi - WINDOW + 1)
            if t < raw[lo]:
                out.append(t + off[lo])
                continue
            b = bisect_right(raw, t, lo, hi)
            out.append(t + _between(t, raw[b - 1], off[b - 1], raw[b], off[b]))
        return out

    def map_array(self, instants: np.ndarray, until: np.ndarray) -> np.ndarray:
        """``map`` of arrays.

        Args:
            instants: Raw-clock ns.
            until: As ``map``'s.

        Returns:
            Realtime ns, int64.
        """
        return np.array(self.map(instants.tolist(), until.tolist()), np.int64)


class RealtimeReads:
    """A capture's reads at once, in arrays.

    ``map_array`` gives what ``RealtimeTrack.map`` gives live, ``changes`` what
    ``RealtimeTrack.add`` names.

    Args:
        raw: Each read's receive time on the raw monotonic clock.
        real: The same instants on the realtime clock.
    """

    def __init__(self, raw: npt.ArrayLike, real: npt.ArrayLike) -> None:
        self.raw = np.asarray(raw, np.int64)
        self.off = np.asarray(real, np.int64) - self.raw

    def map_array(self, instants: np.ndarray, until: np.ndarray,
                  sides: np.ndarray | None = None) -> np.ndarray:
        """``RealtimeTrack.map`` of many instants at once.

        Args:
            instants: Raw-clock ns.
            until: As ``RealtimeTrack.map``'s.
            sides: Per instant, an offset it is known to be near, which decides its side
                of a step between the reads around it (an archive's samples keep only
                their completing reads: the live estimate, which had every read, took
                the side).

        Returns:
            Realtime ns, int64.
        """
        raw, off = self.raw, self.off
        t = np.asarray(instants, np.int64)
        if not len(raw):
            return t
        hi = np.maximum(0, np.searchsorted(raw, np.asarray(until, np.int64), side="right") - 1)
        lo = np.maximum(0, hi - WINDOW + 1)
        b = np.clip(np.searchsorted(raw, t, side="right"), lo + 1, np.maximum(hi, lo + 1))
        b = np.minimum(b, len(raw) - 1)
        ra, oa, rb, ob = raw[b - 1], off[b - 1], raw[b], off[b]
        span = np.maximum(rb - ra, 1)
        with np.errstate(invalid="ignore"):
            linear = oa + np.round((ob - oa) * ((t - ra) / span)).astype(np.int64)
        nearer = np.where(t - ra < rb - t, oa, ob) if sides is None else \
            np.where(np.abs(oa - sides) <= np.abs(ob - sides), oa, ob)
        o = np.where(_jumps(ob - oa, rb - ra), nearer, linear)
        o = np.where(t >= raw[hi], off[hi], np.where(t < raw[lo], off[lo], o))
        return t + o

    @property
    def offset_ns(self) -> int | None:
        """The realtime clock less the raw clock at the last read (None: no read)."""
        return int(self.off[-1]) if len(self.off) else None

    def map(self, instants: list[int], until: list[int]) -> list[int]:
        """``map_array`` of lists, as ``RealtimeTrack.map`` takes them.

        Args:
            instants: Raw-clock ns.
            until: As ``RealtimeTrack.map``'s.

        Returns:
            Realtime ns.
        """
        mapped = self.map_array(np.array(instants, np.int64), np.array(until, np.int64))
        return [int(t) for t in mapped]

    def changes(self) -> list[ClockChange]:
        """Every step and slew the reads show, in order, as ``RealtimeTrack.add`` names them.

        Returns:
            The changes, in the order of the reads that show them.
        """
        raw, off = self.raw, self.off
        if len(raw) < 2:
            return []
        change, apart = np.diff(off), np.diff(raw)
        jumped = _jumps(change, apart)
        at = np.flatnonzero(jumped) + 1
        steps = [ClockChange(ChangeKind.STEP, int(change[i - 1]),
                             int(raw[i] + off[i] - apart[i - 1] // 2),
                             int((raw[i] + raw[i - 1]) // 2), int(apart[i - 1]))
                 for i in at.tolist()]
        stepped = np.concatenate([[0], np.cumsum(np.where(jumped, change, 0))])
        slews, out = _Slews(), []
        start = 0
        while True:
            end = int(np.searchsorted(raw, raw[start] + SPAN_NS, side="left"))
            if end >= len(raw):
                break
            slew = slews.span(int(raw[start]), int(raw[end]), int(raw[end] + off[end]),
                              int(off[end] - off[start] - (stepped[end] - stepped[start])))
            if slew is not None:
                out.append((end, slew))
            start = end
        merged = [(int(i), s) for i, s in zip(at.tolist(), steps, strict=True)] + out
        return [c for _, c in sorted(merged, key=lambda item: item[0])]
