"""The timing layer: from the unit's 32-bit timer to host time, one job per class.

- ``TimerUnwrapper``: timer (uint32) -> 64-bit ``ticks``; names rollovers, resets,
  gaps (dropped samples, counted from the output period) and glitches (corrupt
  timers, flagged ``valid = False``: drop those records).
- ``OnlineClock``: valid (ticks, rx_ns) -> ``time_ns``, the host-clock instant the
  values describe, robust to late delivery, following drift; ``state`` for status.
- ``Timeline``: both in one, fed once per framer batch with (timer, rx_ns); the
  clock judges a timer jump the receive times cannot back (a backlog read after
  a host stall): a gap if the timer ran on, a reset if it restarted.
- ``OfflineClock`` (``bridge.timing.offline``): the recorder's second pass, one
  epoch's (ticks, rx_ns) at once, using records on both sides of each.
- ``RealtimeTrack`` / ``RealtimeReads`` (``bridge.timing.realtime``): receive times are
  on the raw monotonic clock, which nothing steps or slews; these put each instant on
  the host's realtime clock by the offset at that instant, and name its steps and slews
  (``ClockChange``). ``bridge.timing.steps`` finds steps in captures stamped on the
  realtime clock only.

What the caller passes: ``period_ticks`` = decimation x 62.5 (None if unknown);
``filter_delay_ns`` = (M - 1) x 500,000 for filter width M (0xDB); ``floor_ns`` =
the record's line time on a serial line (length x 10 / baud s, in ns: a UART or a
USB-serial adapter), length x 1 us on the unit's own USB port; ``frame_ns`` =
1,000,000 where USB frames carry the bytes (own port or adapter), 0 on a UART;
``serial`` = True behind an adapter. Per record, optionally, the latest earlier read
that ended inside it and the line time of the bytes it held (``Batch.partial``,
``Settings.part_lead_ns``): the tighter bound on a serial line. A bridge that
resets the unit, sets its timer or changes its sampling calls
``expect_discontinuity`` first; a Timeline resets its clock itself on a reset.

All are pure functions of their input sequence: a raw capture replays to the same
output bit for bit however it is cut into calls.
"""

from bridge.timing.clock import ClockState, OnlineClock
from bridge.timing.offline import OfflineClock
from bridge.timing.realtime import ClockChange, RealtimeReads, RealtimeTrack
from bridge.timing.timeline import Timeline, TimelineBatch
from bridge.timing.unwrap import TimerUnwrapper, TimingEvent, Unwrapped

__all__ = ["ClockChange", "ClockState", "OfflineClock", "OnlineClock", "RealtimeReads",
           "RealtimeTrack", "Timeline", "TimelineBatch", "TimerUnwrapper", "TimingEvent",
           "Unwrapped"]
