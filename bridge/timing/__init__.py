"""The timing layer: from the unit's 32-bit timer to host time, one job per class.

- ``TimerUnwrapper``: timer (uint32) -> 64-bit ``ticks``; names rollovers, resets,
  gaps (dropped samples, counted from the output period) and glitches (corrupt
  timers, flagged ``valid = False``: drop those records).
- ``OnlineClock``: valid (ticks, rx_ns) -> ``time_ns``, the host-clock instant the
  values describe, robust to late delivery, following drift; ``state`` for status.
- ``Timeline``: both in one, fed once per framer batch with (timer, rx_ns).

All are pure functions of their input sequence: a raw capture replays to the same
output bit for bit however it is cut into calls.
"""

from bridge.timing.clock import ClockState, OnlineClock
from bridge.timing.timeline import Timeline, TimelineBatch
from bridge.timing.unwrap import TimerUnwrapper, TimingEvent, Unwrapped

__all__ = ["ClockState", "OnlineClock", "Timeline", "TimelineBatch", "TimerUnwrapper",
           "TimingEvent", "Unwrapped"]
