"""A unit's events as ``foxglove.Log`` messages, for viewers' log panels with no plugin.

Foxglove's Log panel and Rerun's text log show gaps, resets and reconnects from them.

One channel for the fleet (``<prefix>/log``): a Log panel shows one topic, and the
fleet's events belong on one page; ``name`` is the unit, so the panel filters by unit.
The text is the one the live viewer shows (bridge/bus/events.py) and names the unit
too, since Rerun's text log shows no ``name``.
"""

from __future__ import annotations

from foxglove_schemas_protobuf.Log_pb2 import Log
from google.protobuf.timestamp_pb2 import Timestamp

from bridge.bus.events import LEVEL, event_text
from bridge.bus.gx3_pb2 import Event

LOG_CLASS = Log
_LEVELS = {"INFO": Log.INFO, "WARN": Log.WARNING, "ERROR": Log.ERROR}


def log_message(unit: str, event: Event, time_ns: int, rate_hz: float = 0.0) -> bytes:
    """The serialized Log of ``event`` at ``time_ns``, its log time in the archive.

    A gap or reset gives the time its lost records span when the unit's output rate is
    known.
    """
    return Log(timestamp=Timestamp(seconds=time_ns // 1_000_000_000,
                                   nanos=time_ns % 1_000_000_000),
               level=_LEVELS[LEVEL.get(event.kind, "INFO")],
               message=event_text(unit, event, rate_hz), name=unit).SerializeToString()
