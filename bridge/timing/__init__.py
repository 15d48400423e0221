"""The timing layer: from the unit's 32-bit timer to host time, one job per class.

- ``TimerUnwrapper``: timer (uint32) -> 64-bit ``ticks``; names rollovers, resets,
  gaps (dropped samples) and glitches (corrupt timers, flagged ``valid = False``: drop
  those records).
- ``OnlineClock``: valid (ticks, rx_ns) -> ``time_ns``, the host-clock instant the
  values describe, robust to late delivery, following drift; ``state`` for status.
- ``Timeline``: both in one, fed once per framer batch with (timer, rx_ns).
- ``OfflineClock``: the export's second pass, one epoch at once, using records on
  both sides of each.
- ``RealtimeTrack`` / ``RealtimeReads``: each instant from the raw monotonic clock onto
  the host's realtime clock, naming its steps and slews (``ClockChange``).
- ``StreamTiming``: one unit's record batches timed from the ``Settings`` that decide
  timing, for the live pipeline and ``gx3 replay`` alike; ``infer_transport`` tells a
  capture's link from its receive times.

All are pure functions of their input sequence: a raw capture replays to the same
output bit for bit however it is cut into calls. The caller passes the unit's settings
and the link (``OnlineClock``'s arguments; ``Settings`` works them out); a bridge that
resets the unit, sets its timer or changes its sampling calls ``expect_discontinuity``
first. The time model behind it all: docs/design/time.md.
"""

from bridge.timing.clock import ClockState, OnlineClock
from bridge.timing.links import Inferred, infer_transport
from bridge.timing.offline import Estimate, OfflineClock
from bridge.timing.rate import RateWindow
from bridge.timing.realtime import ChangeKind, ClockChange, RealtimeReads, RealtimeTrack
from bridge.timing.stream import (
    TRANSPORTS,
    Settings,
    StreamTiming,
    Timed,
    TimedFew,
    filter_delay_ns,
    period_middle_ns,
    record_delay_ns,
)
from bridge.timing.timeline import Timeline, TimelineBatch
from bridge.timing.unwrap import TimerUnwrapper, TimingEvent, TimingKind, Unwrapped

__all__ = ["TRANSPORTS", "ChangeKind", "ClockChange", "ClockState", "Estimate", "Inferred",
           "OfflineClock",
           "OnlineClock", "RateWindow", "RealtimeReads", "RealtimeTrack", "Settings",
           "StreamTiming", "Timed", "TimedFew", "Timeline", "TimelineBatch", "TimerUnwrapper",
           "TimingEvent", "TimingKind", "Unwrapped", "filter_delay_ns", "infer_transport",
           "period_middle_ns", "record_delay_ns"]
