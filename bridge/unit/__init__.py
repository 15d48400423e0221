"""One unit's live bridge: its serial bytes to timed samples, published on Zenoh.

``Pipeline`` owns the port: it brings the unit up, streams or polls, times every
record and keeps the unit alive through faults, handing samples, events, status and
info to a ``Sink``; ``BusSink`` is the sink of ``gx3 bridge``, which publishes them
under the unit's keys. How it fits into the product: ``docs/design/architecture.md``.
"""

from bridge.unit.pipeline import (
    Counters,
    EventKind,
    Options,
    Pipeline,
    Sink,
    TimedSamples,
    UnitEvent,
    UnitState,
)
from bridge.unit.service import BusSink, claim_name

__all__ = ["BusSink", "Counters", "EventKind", "Options", "Pipeline", "Sink", "TimedSamples",
           "UnitEvent", "UnitState", "claim_name"]
