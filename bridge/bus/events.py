"""How an Event reads to a person: its severity and one line of text.

The same in every viewer (Rerun's text log, Foxglove's Log panel) and in the log.
"""

from __future__ import annotations

from bridge.bus.gx3_pb2 import Event

#: Severity of each event kind, as Rerun names it (TextLogLevel): faults in the data
#: warn, a lost port or two sources on one unit are errors, the rest inform.
LEVEL = {
    Event.GAP: "WARN",
    Event.RESET: "WARN",
    Event.ROLLOVER: "INFO",
    Event.GLITCH: "WARN",
    Event.RECONNECT: "INFO",
    Event.DISCONNECT: "ERROR",
    Event.RESYNC: "WARN",
    Event.BRING_UP: "INFO",
    Event.COMMAND: "INFO",
    Event.LOST: "WARN",
    Event.REJECTED: "WARN",
    Event.SHED: "WARN",
    Event.DUPLICATE_UNIT: "ERROR",
    Event.HOST_CLOCK_STEP: "WARN",
    Event.HOST_CLOCK_SLEW: "WARN",
    Event.HOST_CLOCK_OFFSET: "WARN",
}
#: Kinds whose count is records lost: they span count output periods.
_RECORDS = {Event.GAP, Event.RESET}
#: Kinds the recorder writes about messages: their span is time_ns to end_time_ns.
_MESSAGES = {Event.LOST, Event.REJECTED, Event.SHED}


def event_text(unit: str, event: Event, rate_hz: float = 0.0) -> str:
    """One line for people about an event.

    Args:
        unit: The unit's name.
        event: The event.
        rate_hz: The unit's output rate, where known: records lost are then given the
            time they span too.

    Returns:
        Unit, kind, how many when more than one or when lost (with the time they span:
        records at ``rate_hz``, messages from their first to their last), and the detail.
    """
    text = f"{unit} {Event.Kind.Name(event.kind)}"
    count = event.count
    if event.kind in _RECORDS and count:
        span = f", {count / rate_hz:.3g} s" if rate_hz > 0 else ""
        text += f" ({count:,} record{'s' * (count != 1)}{span})"
    elif event.kind in _MESSAGES and count:
        leaf = f" {event.leaf}" if event.leaf else ""
        span = (f", {(event.end_time_ns - event.time_ns) / 1e9:.3g} s"
                if event.end_time_ns > event.time_ns else "")
        text += f" ({count:,}{leaf} message{'s' * (count != 1)}{span})"
    elif count > 1:
        text += f" ({count:,})"
    return f"{text}: {event.detail}" if event.detail else text
