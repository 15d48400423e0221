"""How an Event reads to a person: its severity and one line of text, the same in every
viewer (Rerun's text log, Foxglove's Log panel)."""

from __future__ import annotations

from bridge.bus.gx3_pb2 import Event

#: Severity of each event kind, as Rerun names it (TextLogLevel): faults in the data
#: warn, a lost port is an error, the rest inform.
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
}
#: Kinds whose count is records lost: they span count output periods.
_LOST = {Event.GAP, Event.RESET}


def event_text(unit: str, event: Event, rate_hz: float = 0.0) -> str:
    """One line: unit, kind, how many when more than one (and, for records lost at a
    known output rate ``rate_hz``, the time they span), and the detail."""
    text = f"{unit} {Event.Kind.Name(event.kind)}"
    if event.count > 1 or (event.kind in _LOST and event.count):
        text += f" ({event.count:,}"
        if event.kind in _LOST and rate_hz > 0:
            text += f" record{'s' * (event.count != 1)}, {event.count / rate_hz:.3g} s"
        text += ")"
    return f"{text}: {event.detail}" if event.detail else text
