"""The 32-bit timer as a 64-bit tick count, with its discontinuities named.

The timer counts 62,500 ticks a second and wraps every ~19 h; between two records it
advances by whole output periods (decimation x 62.5 ticks), more than one being a gap
of dropped samples. A value off that lattice is a reset or a corrupt timer (a glitch
that passed the checksum); the next record tells which, so such a record is dropped at
once and named when the next one arrives. After an unannounced reset that costs the
first record of the new epoch: a bridge that itself resets the unit, sets the timer or
changes the sampling calls ``expect_discontinuity`` and loses nothing. A jump the
receive times cannot back (a backlog read after a host stall) is judged against the
clock model: ``update(..., ask=True)`` stops before it for the caller to ``judge`` it,
as ``Timeline`` does. How each case is told apart: docs/design/time.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from bridge.protocol.table import TICKS_PER_SECOND

TIMER_MODULUS = 1 << 32
NS_PER_TICK = 1_000_000_000 // TICKS_PER_SECOND  # 16,000 ns
#: How much later than the record before it a record may be received and still be
#: believed: covers stalled reads and a scheduler that sleeps for a while.
HOST_SLACK_NS = 500_000_000
#: How far a timer that ran on through a reconnect may disagree with the host's elapsed
#: time (receive latency on both sides of the outage, and a stalled read).
CONTINUATION_SLACK_S = 0.1
#: How far past the clock model's prediction a record may be and still be believed: the
#: model rests on the earliest receipts, a few ms after the sample instants on a busy host.
MODEL_SLACK_TICKS = TICKS_PER_SECOND // 10
_LATTICE_TOLERANCE = 0.5  # ticks: each timer value is rounded to the nearest half up
_SCALAR_BATCH = 16  # records; below this plain integers beat NumPy's cost per call
_FAST_WINDOW = 8192  # records the bulk path looks at in one go
_SLOW_RUN = 32  # records taken one by one before the bulk path is tried again


class TimingKind(StrEnum):
    """What a timeline can tell of the unit's timer."""

    ROLLOVER = "rollover"  # the 32-bit timer wrapped; ticks ran on
    RESET = "reset"  # the timer restarted (0xFE, 0xD7, a power cycle)
    GAP = "gap"  # records missing: ticks jumped by whole output periods
    GLITCH = "glitch"  # a corrupt timer that is neither: the record is dropped


@dataclass(frozen=True)
class TimingEvent:
    """Something the timeline did that a user should hear about (``gx3/<unit>/event``).

    ``index`` is the record's position in the ``update`` call that found it (for a
    glitch found one record late, possibly negative: in an earlier call); ``ticks``
    the unwrapped ticks of the record that confirmed it; ``count`` the samples
    missing (gap), records dropped (glitch, reset) or the rollovers so far.
    """

    kind: TimingKind
    index: int
    ticks: int
    count: int


@dataclass
class Unwrapped:
    """One ``update``'s result, aligned with its input records."""

    ticks: npt.NDArray[np.int64]  # -1 where not valid
    valid: npt.NDArray[np.bool_]  # False: a corrupt or unconfirmed timer; drop the record
    events: list[TimingEvent] = field(default_factory=list)
    dropped: int = 0  # samples the unit produced that never arrived (gaps)
    intact: bool = False  # known without looking: every record is valid
    #: With ``ask``: the index of a record whose jump only the clock model can judge;
    #: the result stops before it (``judge``, then ``update`` from there on).
    pending: int | None = None

    @property
    def all_valid(self) -> bool:
        """Whether every record is valid."""
        return self.intact or bool(self.valid.all())


@dataclass
class _Anchor:
    timer: int
    ticks: int
    rx: int | None


class TimerUnwrapper:
    """Unwraps timers record by record; state carries across ``update`` calls.

    ``dropped``, ``glitches``, ``resets`` and ``rollovers`` count what it found so far.

    Args:
        period_ticks: The output period in ticks (decimation x 62.5), or None when
            unknown: then gaps are not counted and only host time checks jumps.

    Raises:
        ValueError: ``period_ticks`` is not positive.
    """

    def __init__(self, period_ticks: float | None = None) -> None:
        if period_ticks is not None and period_ticks <= 0:
            raise ValueError(f"period_ticks must be positive, got {period_ticks}")
        self.period_ticks = period_ticks
        self._ref: _Anchor | None = None
        self._candidate: tuple[_Anchor, int] | None = None  # and its record number
        self._fresh = True
        self._asking = False  # a record waits for the model's judgement
        self._horizon: tuple[int | None] | None = None  # the model's answer, once given
        self._records = 0
        self._last_ticks = -1
        self.dropped = 0
        self.glitches = 0
        self.resets = 0
        self.rollovers = 0

    def expect_discontinuity(self, period_ticks: float | None = None) -> None:
        """The next record starts a new timer epoch or phase (the bridge caused it).

        Args:
            period_ticks: The new output period, if it changed.
        """
        if period_ticks is not None:
            self.period_ticks = period_ticks
        self._fresh = True

    def judge(self, horizon: int | None) -> None:
        """The clock model's answer for the record an ``update`` stopped before.

        Args:
            horizon: The most ticks a record received when it was can carry
                (``OnlineClock.horizon``); None: the model has no line yet, so the jump
                is doubted as any other.
        """
        self._horizon = (horizon,)

    # --- classification ----------------------------------------------------------------
    def _advance(self, ref: _Anchor, timer: int, rx: int | None) -> tuple[int, int] | None:
        """Ticks from ``ref`` to this record and periods spanned, or None if implausible."""
        d = (timer - ref.timer) % TIMER_MODULUS
        host = None if rx is None or ref.rx is None else (rx - ref.rx) // NS_PER_TICK
        if host is not None and host > TIMER_MODULUS // 2:
            d += max(0, (host + HOST_SLACK_NS // NS_PER_TICK - d) // TIMER_MODULUS) \
                * TIMER_MODULUS
        if d <= 0 or (host is not None and d > host + HOST_SLACK_NS // NS_PER_TICK):
            return None
        if self.period_ticks is None:
            return d, 1
        n = round(d / self.period_ticks)
        if n < 1 or abs(d - n * self.period_ticks) > _LATTICE_TOLERANCE:
            return None
        return d, n

    # --- update --------------------------------------------------------------------------
    def update(self, timer: npt.ArrayLike, rx_ns: npt.ArrayLike | None = None,
               ask: bool = False) -> Unwrapped:
        """Unwrap one batch of timers.

        Runs of records one period apart go through in bulk, the rest record by record;
        the result does not depend on where the batch is cut.

        Args:
            timer: The records' timers (uint32).
            rx_ns: Each record's receive time, if known.
            ask: Stop at a record whose jump is ahead of its receive time, which only the
                clock model can judge (``pending``); without, such a jump is doubted like
                any other.

        Returns:
            Ticks, validity and events, aligned with the records.

        Raises:
            ValueError: ``timer`` and ``rx_ns`` differ in length.
        """
        timers = np.asarray(timer).astype(np.int64)
        rx = None if rx_ns is None else np.asarray(rx_ns, np.int64)
        if rx is not None and rx.shape != timers.shape:
            raise ValueError(f"timer and rx_ns differ in length: {timers.shape} vs {rx.shape}")
        parts: list[tuple[int, Unwrapped]] = []
        done, rest, rest_rx = 0, timers, rx
        while True:
            out = self._fast(rest, rest_rx) or self._slow(rest, rest_rx, ask)
            parts.append((done, out))
            self._records += len(out.ticks)
            done += len(out.ticks)
            if self._asking or done >= len(timers):
                joined = _joined(parts)
                if self._asking:
                    joined.pending, self._asking = done, False
                return joined
            rest, rest_rx = timers[done:], None if rx is None else rx[done:]

    def update_few(self, timers: list[int],
                   rx_ns: list[int] | None) -> tuple[list[int], list[TimingEvent]] | None:
        """``update`` of a few records in plain integers (a live bridge gets one or two a read).

        Args:
            timers: The records' timers.
            rx_ns: Their receive times, if known.

        Returns:
            Their ticks and rollovers, when each is one period after the last; None when
            they are not, or the state is not plain: nothing changed, ask ``update``.
        """
        ref = self._ref
        if (ref is None or self._candidate is not None or self._fresh or not timers
                or len(timers) > _SCALAR_BATCH):
            return None
        run = self._fast_scalar(ref, timers, rx_ns)
        if run is not None:
            self._records += len(timers)
        return run

    def _fast(self, timers: np.ndarray, rx: np.ndarray | None) -> Unwrapped | None:
        """The common case in one go: the leading records each one period after the last.

        None when not even the first is.
        """
        ref = self._ref
        if ref is None or self._candidate is not None or self._fresh or not len(timers):
            return None
        if len(timers) <= _SCALAR_BATCH:
            run = self._fast_scalar(ref, timers.tolist(), None if rx is None else rx.tolist())
            return None if run is None else Unwrapped(
                np.array(run[0], np.int64), np.ones(len(timers), bool), run[1], intact=True)
        timers = timers[:_FAST_WINDOW]
        rx = None if rx is None else rx[:_FAST_WINDOW]
        d = np.diff(timers, prepend=ref.timer) % TIMER_MODULUS
        ok = d > 0
        if self.period_ticks is not None:
            ok &= np.abs(d - self.period_ticks) <= _LATTICE_TOLERANCE
        if rx is not None and ref.rx is not None:
            host = np.diff(rx, prepend=ref.rx) // NS_PER_TICK
            ok &= (d <= host + HOST_SLACK_NS // NS_PER_TICK) & (host <= TIMER_MODULUS // 2)
        if not ok.all():
            good = int(np.argmin(ok))
            if not good:
                return None
            timers, d = timers[:good], d[:good]
            rx = None if rx is None else rx[:good]
        ticks = ref.ticks + np.cumsum(d)
        events = []
        for i in np.flatnonzero(np.diff(timers, prepend=ref.timer) < 0).tolist():
            self.rollovers += 1
            events.append(TimingEvent(TimingKind.ROLLOVER, i, int(ticks[i]), self.rollovers))
        self._ref = _Anchor(int(timers[-1]), int(ticks[-1]),
                            None if rx is None else int(rx[-1]))
        self._last_ticks = int(ticks[-1])
        return Unwrapped(ticks.astype(np.int64), np.ones(len(timers), bool), events,
                         intact=True)

    def _fast_scalar(self, ref: _Anchor, timers: list[int],
                     rx: list[int] | None) -> tuple[list[int], list[TimingEvent]] | None:
        """``_fast`` for a few records, in plain integers.

        The same rules without NumPy's fixed cost per call. Their ticks and rollovers;
        None (nothing changed) unless every one is one period after the last.
        """
        period, slack = self.period_ticks, HOST_SLACK_NS // NS_PER_TICK
        prev_t, prev_rx, value = ref.timer, ref.rx, ref.ticks
        ticks: list[int] = []
        wrapped: list[int] = []
        for i, t in enumerate(timers):
            d = (t - prev_t) % TIMER_MODULUS
            if d <= 0 or (period is not None and abs(d - period) > _LATTICE_TOLERANCE):
                return None
            if rx is not None:
                if prev_rx is not None:
                    host = (rx[i] - prev_rx) // NS_PER_TICK
                    if d > host + slack or host > TIMER_MODULUS // 2:
                        return None
                prev_rx = rx[i]
            value += d
            if t < prev_t:
                wrapped.append(i)
            ticks.append(value)
            prev_t = t
        events = []
        for i in wrapped:
            self.rollovers += 1
            events.append(TimingEvent(TimingKind.ROLLOVER, i, ticks[i], self.rollovers))
        self._ref = _Anchor(timers[-1], value, None if rx is None else rx[-1])
        self._last_ticks = value
        return ticks, events

    def _slow(self, timers: np.ndarray, rx: np.ndarray | None, ask: bool) -> Unwrapped:
        """Record by record, at least ``_SLOW_RUN`` of them.

        And on until the state is plain again (an anchor, nothing in doubt), so the bulk
        path can take over; or up to a record that waits for the clock model.
        """
        n = len(timers)
        ticks = np.full(n, -1, np.int64)
        valid = np.zeros(n, bool)
        out = Unwrapped(ticks, valid)
        for i in range(n):
            t = int(timers[i])
            r = None if rx is None else int(rx[i])
            value = self._step(t, r, i, out, ask)
            if self._asking:
                out.ticks, out.valid = ticks[:i], valid[:i]
                break
            if value is not None:
                ticks[i] = value
                valid[i] = True
                self._last_ticks = value
            if i + 1 >= _SLOW_RUN and self._candidate is None and not self._fresh:
                out.ticks, out.valid = ticks[: i + 1], valid[: i + 1]
                break
        return out

    def _step(self, t: int, r: int | None, i: int, out: Unwrapped, ask: bool) -> int | None:
        ref = self._ref
        if ref is None:
            self._ref = _Anchor(t, t, r)
            self._fresh = False
            return t
        step = self._advance(ref, t, r)
        if step is not None:
            held = int(self._candidate is not None)  # arrived, corrupt: not a gap
            self._drop_candidate(out)
            self._fresh = False
            return self._accept(ref, t, r, step, i, out, held)
        if self._fresh:
            host = None if r is None or ref.rx is None else (r - ref.rx) / NS_PER_TICK
            d = self._continuation(ref, t, host)
            if d is None and ask and host is not None:  # the receive times may be late
                if self._horizon is None:
                    self._asking = True
                    return None
                horizon, self._horizon = self._horizon[0], None
                if horizon is not None:
                    d = self._continuation(ref, t, horizon - ref.ticks)
            if d is not None:
                self._drop_candidate(out)
                self._fresh = False
                periods = max(1, round(d / self.period_ticks)) if self.period_ticks else 1
                return self._accept(ref, t, r, (d, periods), i, out)
        cand = self._candidate
        if self._fresh or (cand is not None and self._advance(cand[0], t, r) is not None):
            if cand is not None and not self._fresh:
                first = cand[0]
                first.ticks = self._last_ticks + self._host_ticks(first.rx)
                self._candidate = None
                self._ref = first
                step = self._advance(first, t, r)
                assert step is not None
                value = self._accept(first, t, r, step, i, out, step[1] - 1)
                dropped = 1
            else:
                self._drop_candidate(out)
                value, dropped = self._last_ticks + self._host_ticks(r), 0
                self._ref = _Anchor(t, value, r)
            self._fresh = False
            self.resets += 1
            out.events.append(TimingEvent(TimingKind.RESET, i, value, dropped))
            return value
        step = self._advance(ref, t, None) if ask and r is not None and ref.rx is not None \
            else None
        if step is not None:  # on the lattice, only too far ahead of the receive times
            if self._horizon is None:
                self._asking = True
                return None
            horizon = self._horizon[0]
            self._horizon = None
            if horizon is not None and ref.ticks + step[0] <= horizon + MODEL_SLACK_TICKS:
                held = int(cand is not None)
                self._drop_candidate(out)
                return self._accept(ref, t, r, step, i, out, held)
        self._drop_candidate(out)
        self._candidate = (_Anchor(t, -1, r), self._records + i)
        return None

    @staticmethod
    def _continuation(ref: _Anchor, t: int, elapsed: float | None) -> int | None:
        """Ticks since ``ref`` if the timer ran on through an announced discontinuity.

        A restarted stream starts on a new phase of the decimation lattice, so only
        host time can tell a timer that ran on (a reconnect: count the gap) from one
        that restarted (a reset): the advance must match the ticks ``elapsed`` since
        ``ref`` by the host's clock (receive times, or the clock model when ``ref`` was
        received late).
        """
        if elapsed is None or elapsed < 0:
            return None
        d = (t - ref.timer) % TIMER_MODULUS
        d += round((elapsed - d) / TIMER_MODULUS) * TIMER_MODULUS
        tolerance = CONTINUATION_SLACK_S * TICKS_PER_SECOND + 2e-4 * elapsed
        return d if d > 0 and abs(d - elapsed) <= tolerance else None

    def _host_ticks(self, r: int | None) -> int:
        """Ticks a new epoch starts at: after the last, by the host's elapsed time."""
        ref = self._ref
        if r is None or ref is None or ref.rx is None:
            return 1
        return max(1, (r - ref.rx) // NS_PER_TICK)

    def _accept(self, ref: _Anchor, t: int, r: int | None, step: tuple[int, int], i: int,
                out: Unwrapped, held: int = 0) -> int:
        """Take a record ``step`` after ``ref``.

        ``held`` records in between arrived corrupt (they are glitches, not missing
        samples).
        """
        d, periods = step
        missing = periods - 1 - held
        value = ref.ticks + d
        wraps = (ref.timer + d) // TIMER_MODULUS
        for _ in range(wraps):
            self.rollovers += 1
            out.events.append(TimingEvent(TimingKind.ROLLOVER, i, value, self.rollovers))
        if missing > 0 and self.period_ticks is not None:
            out.events.append(TimingEvent(TimingKind.GAP, i, value, missing))
            out.dropped += missing
            self.dropped += missing
        self._ref = _Anchor(t, value, r)
        return value

    def _drop_candidate(self, out: Unwrapped) -> None:
        """The record held in doubt agreed with nothing after it: it was corrupt."""
        if self._candidate is None:
            return
        number = self._candidate[1]
        self._candidate = None
        self.glitches += 1
        out.events.append(TimingEvent(TimingKind.GLITCH, number - self._records,
                                      self._last_ticks, 1))


def _joined(parts: list[tuple[int, Unwrapped]]) -> Unwrapped:
    """The results of consecutive stretches of one batch (each at its start) as one."""
    if len(parts) == 1:
        return parts[0][1]
    events = [TimingEvent(e.kind, e.index + start, e.ticks, e.count)
              for start, part in parts for e in part.events]
    return Unwrapped(np.concatenate([p.ticks for _, p in parts]),
                     np.concatenate([p.valid for _, p in parts]), events,
                     sum(p.dropped for _, p in parts), all(p.intact for _, p in parts))
