"""Which link a capture came over, from its receive times alone.

A capture from another program says nothing of its link, yet the clock model needs
it: a frame clock to take out on USB, a line time to take out on a serial line. The
reads tell: on a UART, reads that end mid-record fit the line at one baud rate; over
USB, reads crowd just after the host's 1 ms frames; an adapter shows in whole 62-byte
packets, a 16 ms latency timer, or reads that end inside records, which the unit's own
USB port never gives (it hands over whole records). The evidence and the order it is
weighed in: docs/design/time.md.

Blind spot: an adapter whose frames never once fell inside a record over the whole
capture (a unit in step with the host's frames, its records shorter than the gaps
between them) reads as the unit's own USB port; nothing in its reads tells the two
apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bridge.device.link import ADAPTER_PACKET_BYTES, DEFAULT_LATENCY_TIMER_MS
from bridge.protocol.framer import Framer
from bridge.protocol.table import REPLIES, TICKS_PER_SECOND
from bridge.timing._fit import frame_after, grid_histogram, grid_phase
from bridge.timing.stream import USB_FRAME_NS
from bridge.timing.unwrap import NS_PER_TICK, TIMER_MODULUS

_BIN_NS = 10_000
_WINDOW_BINS = 10  # reads counted within 0.1 ms either side of a phase
_OUTLIER_S = 0.002  # a stalled read is left out of the clock fit
_SIGMAS = 4.0
_PACKETS = 0.5  # fraction of reads made of whole packets that only a 16 ms timer gives
_TIMER_GAPS = 0.3  # fraction of reads a 16 ms timer's length after the one before
_LINE_READS = 50  # neighbouring mid-record reads needed to judge a serial line
_LINE_SPAN_NS = 1e9  # neighbours this close on the unit's clock (its error adds little)
_LINE_FIT = 0.6  # byte times: a UART fits within ~1/3, frames several
_FRAMED_FIT = 1.2  # byte times: reads at their frames lie within one, a wrong rate spreads
_STRETCH_NS = 60_000_000_000
_WRAPS = 2  # times k must jump back within a stretch
# reads ending mid-record, which the unit's own USB port never gives: more than a damaged
# byte here and there makes
_SPLIT_READS = 20
_SPLIT_SHARE = 0.002
BAUD_GUESSES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)


@dataclass(frozen=True)
class Inferred:
    """The link a capture's reads show, with what showed it.

    ``transport`` as ``Settings.transport``; ``latency_timer_ms`` an adapter's;
    ``evidence`` one line; ``baud`` a serial line's (a UART's or behind an adapter),
    where its reads show it.
    """

    transport: str
    latency_timer_ms: int | None
    evidence: str
    baud: int | None = None  # a serial line's, where its reads show it

    def describe(self) -> str:
        """One line for people.

        Returns:
            The transport, an adapter's latency timer, and the evidence.
        """
        timer = f", {self.latency_timer_ms} ms latency timer" if self.latency_timer_ms else ""
        return f"transport {self.transport}{timer} ({self.evidence})"


def crowding(phase_ns: np.ndarray) -> float:
    """How sharply times crowd just after one phase of a 1 ms cycle.

    Args:
        phase_ns: The times (ns; only their phase in the millisecond counts).

    Returns:
        The most reads in 0.1 ms after any phase less those in the 0.1 ms before it, as a
        fraction of all: 0 for times spread evenly; about 0.11 for a frame read after an
        exponential OS latency of 0.8 ms mean, 0.28 at 0.3 ms.
    """
    if not len(phase_ns):
        return 0.0
    bins = USB_FRAME_NS // _BIN_NS
    hist = np.bincount((np.mod(phase_ns, USB_FRAME_NS) // _BIN_NS).astype(np.int64),
                       minlength=bins)
    after = np.convolve(np.concatenate([hist, hist]), np.ones(_WINDOW_BINS, np.int64),
                        "valid")[:bins]
    before = np.roll(after, _WINDOW_BINS)
    return float((after - before).max() / len(phase_ns))


def infer_transport(rx_ns: np.ndarray, data: Sequence[bytes], record: int,
                    little_endian: bool = False) -> Inferred:
    """The link a capture came over.

    Args:
        rx_ns: Each read's receive time.
        data: Each read's bytes.
        record: The data record the capture streams.
        little_endian: The float byte order of its records.

    Returns:
        The transport, an adapter's latency timer, a UART's baud rate where the reads
        show them, and the evidence.
    """
    rx_ns = np.asarray(rx_ns, np.int64)
    sizes = np.array([len(d) for d in data], np.int64)
    ends = np.cumsum(sizes)
    framer = Framer([record], little_endian=little_endian)
    batches = [b for b in framer.feed_reads(b"".join(data), ends, rx_ns) + framer.flush()
               if b.code == record]
    if not batches:
        return Inferred("uart", None, "no records to judge by")
    length = REPLIES[record].length
    starts = np.concatenate([b.offsets for b in batches])
    completions = np.concatenate([b.rx_ns for b in batches])
    ticks = np.concatenate([[0], np.cumsum(np.mod(np.diff(
        np.concatenate([b["timer"] for b in batches]).astype(np.int64)), np.int64(TIMER_MODULUS)))])
    # reads whose last byte falls inside a record: which record, and how much of it
    inside = np.searchsorted(starts, ends, "left") - 1
    got = ends - starts[np.maximum(inside, 0)]
    mid = (inside >= 0) & (got < length) & (sizes > 0)
    ends_mid = float(mid.mean())
    said = f"{ends_mid:.0%} end mid-record"
    packets = float(np.mean((sizes % ADAPTER_PACKET_BYTES == 0) & (sizes > 0)))
    period_s = float(np.median(np.diff(ticks))) / TICKS_PER_SECOND if len(ticks) > 1 else 1.0
    rate, against_unit = _unit_fit(ticks, completions)
    bauds = [b for b in BAUD_GUESSES if b / 10 * period_s >= length]
    line = _line_fit(ticks, rate, rx_ns[mid], got[mid], inside[mid], bauds)
    host = crowding(completions)
    unit = crowding(against_unit)
    noise = _SIGMAS * np.sqrt(4 * _WINDOW_BINS * _BIN_NS / USB_FRAME_NS / len(completions))
    if line is not None and line[0] < _LINE_FIT:
        return Inferred("uart", None, f"{said}, each holding every byte the line had "
                                      f"carried by then at {line[1]} baud", line[1])
    if line is None and unit - host > noise:
        return Inferred("uart", None, f"reads follow the unit's clock, not the host's 1 ms "
                                      f"frames; {said}")
    why = ("reads crowd just after 1 ms frames" if host - unit > noise else
           "reads end mid-record short of what a serial line had carried" if line else
           "reads keep step with the host's frames and the unit's clock alike")
    gaps = np.diff(rx_ns) / 1e6
    timer_gaps = float(np.mean((gaps > 14.0) & (gaps < 18.5))) if len(gaps) else 0.0
    if packets > _PACKETS or (timer_gaps > _TIMER_GAPS and not 14.0 < period_s * 1e3 < 18.5):
        return Inferred("usb-serial", DEFAULT_LATENCY_TIMER_MS, f"{why}; {said}; " + (
            f"{packets:.0%} are whole 62-byte packets" if packets > _PACKETS else
            f"{timer_gaps:.0%} come 16 ms after the one before"))
    # The unit's own USB port hands over whole records: a read that ends inside one is a
    # serial line's, behind an adapter. Each such read holds every byte that had crossed
    # the line by its frame, so it fits the line at the adapter's baud rate as a UART's
    # read does at its own time.
    if int(mid.sum()) >= _SPLIT_READS and ends_mid >= _SPLIT_SHARE:
        edge = grid_phase(grid_histogram(completions, USB_FRAME_NS), USB_FRAME_NS)
        baud = _framed_baud(ticks[inside[mid]], rate,
                            frame_after(rx_ns[mid], edge, USB_FRAME_NS), got[mid], bauds)
        return Inferred("usb-serial", 1, f"{why}; {said}" + (
            f", each holding every byte the line had carried by its frame at {baud} baud"
            if baud else ""), baud)
    return Inferred("usb", None, f"{why}; {said}")


def _line_fit(ticks: np.ndarray, rate: float, mid_at: np.ndarray,
              mid_bytes: np.ndarray, mid_record: np.ndarray,
              bauds: Sequence[int]) -> tuple[float, int] | None:
    """How well reads that end mid-record fit a plain serial line.

    At the baud rate that fits best among ``bauds`` (those that carry the stream):
    (score, baud), or None with too few such reads to tell. ``rate``: host seconds per
    second of the unit's clock (``_unit_fit``).

    On a UART a read takes every byte that has crossed the line, so its time less the
    record's bytes so far times the byte time falls within one byte time of the
    record's start, which follows the unit's clock. Behind USB frames the reads come
    an OS latency after the frame that carried the bytes, which no baud rate takes
    out. The score is the median disagreement between neighbouring such reads, in
    byte times (about 1/3 on a UART, several behind frames).
    """
    if len(mid_at) < _LINE_READS or len(ticks) < 2 or not bauds:
        return None
    record_ns = ticks[mid_record] / TICKS_PER_SECOND * 1e9 * rate
    near = np.abs(np.diff(record_ns)) < _LINE_SPAN_NS
    if near.sum() < _LINE_READS:
        return None
    spread = {}
    for baud in bauds:
        start = mid_at - mid_bytes * (1e10 / baud) - record_ns
        spread[baud] = float(np.median(np.abs(np.diff(start)[near])))
    baud = min(spread, key=spread.__getitem__)  # a wrong byte time spreads with the count
    return spread[baud] / (1e10 / baud), baud


def _framed_baud(ticks: np.ndarray, rate: float, frames: np.ndarray, held: np.ndarray,
                 bauds: Sequence[int]) -> int | None:
    """The baud rate at which reads that end inside records, at their frames, fit the line.

    A read at frame F holding k bytes of a record says the record began within a byte
    time before F less k byte times: at the true byte time these instants, less the
    unit's clock, lie within a byte time (and a tick of its timer) of each other; at
    another, they spread by the difference times the spread of k. Judged over minute-long
    stretches in which k takes values back and forth (several frames inside a record, or a
    phase that sweeps the frame); None where no baud rate stands out: a unit crawling
    against the frames moves k as steadily as a rate error would.

    Args:
        ticks: The split records' ticks.
        rate: Host seconds per second of the unit's clock (``_unit_fit``).
        frames: The frame each read's bytes came at (upper bound).
        held: The record's bytes each read held.
        bauds: The baud rates that carry the stream.
    """
    at = ticks / TICKS_PER_SECOND * 1e9 * rate
    stretch = (at // _STRETCH_NS).astype(np.int64)
    spread = {}
    for baud in bauds:
        start = frames - held * (1e10 / baud) - at
        widths = []
        for k in np.unique(stretch):
            here = stretch == k
            # k must jump back here and there: a unit crawling against the frames
            # splits its records at a byte that moves steadily, and a steady drift of k
            # is what a rate error does too
            if here.sum() < _LINE_READS or (np.abs(np.diff(held[here])) >= 3).sum() < _WRAPS:
                continue
            # less a line: the rate is known only to what frames quantise it to
            x, y = at[here] - at[here][0], start[here] - start[here][0]
            slope, offset = np.polyfit(x, y, 1)
            widths.append(float(np.ptp(np.percentile(y - slope * x - offset, [5, 95]))))
        if widths:
            spread[baud] = float(np.median(widths))
    if not spread:
        return None
    ranked = sorted(spread, key=spread.__getitem__)
    best = ranked[0]
    clear = len(ranked) == 1 or spread[ranked[1]] > 2 * spread[best]
    # within a byte time, and the timer's tick: a record's ticks are its cycle's to a tick
    fits = spread[best] < _FRAMED_FIT * 1e10 / best + NS_PER_TICK
    return best if fits and clear else None


def _unit_fit(ticks: np.ndarray, completions: np.ndarray) -> tuple[float, np.ndarray]:
    """A line through the records' ticks and receive times, stalls left out.

    Returns host seconds per second of the unit's clock, and each receive time against
    it (ns), which is what reads follow on a serial line.
    """
    x = ticks / TICKS_PER_SECOND
    y = (completions - completions[0]) / 1e9
    keep = np.ones(len(x), bool)
    slope, offset = 1.0, 0.0
    for _ in range(3):
        if keep.sum() < 2:
            break
        slope, offset = (float(v) for v in np.polyfit(x[keep], y[keep], 1))
        residual = y - (offset + slope * x)
        keep = np.abs(residual - np.median(residual[keep])) < _OUTLIER_S
    return slope, np.asarray(np.round((y - (offset + slope * x)) * 1e9), np.int64)
