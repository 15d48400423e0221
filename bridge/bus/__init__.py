"""The Zenoh side: keys, the published messages, sessions, publishing and subscribing.

``keys`` spells every key (``gx3/<unit>/imu``, ``status``, ``event``, ``info``,
``command``, ``raw``, ``alive``); ``gx3_pb2`` holds the messages generated from
schemas/gx3.proto (``ImuSample``, ``Status``, ``Event``, ``Info``, ``HostClock``);
``codec`` encodes and decodes ImuSamples in bulk, byte-identical to protobuf;
``integrity`` seals each payload with its CRC-32 and checks it on arrival; ``session``
opens sessions with errors that say why one cannot connect; ``publish`` declares one
unit's publishers and ``subscribe`` hands an app what arrives (``bridge.subscribe``, the
entry point for applications). How they fit together, keys and integrity included:
docs/design/architecture.md.

The names below are imported on first use, so that ``bridge.bus.keys`` or
``bridge.bus.codec`` alone (as an archive's reader uses them) does not load Zenoh.

```python
from bridge.bus import UnitPublisher, open_session

session = open_session(connect=["tcp/10.0.0.5:7447"])
with session, UnitPublisher(session, "imu0") as pub:
    pub.publish_samples(batch, ticks, time_ns)  # a framer's Batch, its timing
```
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported

if TYPE_CHECKING:
    from bridge.bus.codec import decode_batch, encode_batch, parse, peek, record_quantities
    from bridge.bus.events import event_text
    from bridge.bus.integrity import intact, read_raw_time, read_time, seal
    from bridge.bus.keys import (
        ENCODINGS,
        PREFIX,
        UnitKeys,
        check_prefix,
        check_unit,
        fleet,
        unit_of,
    )
    from bridge.bus.publish import UnitPublisher
    from bridge.bus.remote import ask_units
    from bridge.bus.routes import PublisherKeys
    from bridge.bus.schema import file_descriptor_set
    from bridge.bus.session import ZenohOptions, open_session
    from bridge.bus.subscribe import Arrivals, RawMessage, SampleBatch, Subscription

__all__ = [
    "ENCODINGS",
    "PREFIX",
    "Arrivals",
    "PublisherKeys",
    "RawMessage",
    "SampleBatch",
    "Subscription",
    "UnitKeys",
    "UnitPublisher",
    "ZenohOptions",
    "ask_units",
    "check_prefix",
    "check_unit",
    "decode_batch",
    "encode_batch",
    "event_text",
    "file_descriptor_set",
    "fleet",
    "intact",
    "open_session",
    "parse",
    "peek",
    "read_raw_time",
    "read_time",
    "record_quantities",
    "seal",
    "unit_of",
]

# the module of each name above, imported when the name is first asked for
_MODULES = {
    **dict.fromkeys(("decode_batch", "encode_batch", "parse", "peek", "record_quantities"),
                    ".codec"),
    "event_text": ".events",
    **dict.fromkeys(("intact", "read_raw_time", "read_time", "seal"), ".integrity"),
    **dict.fromkeys(("ENCODINGS", "PREFIX", "UnitKeys", "check_prefix", "check_unit", "fleet",
                     "unit_of"), ".keys"),
    "UnitPublisher": ".publish",
    "ask_units": ".remote",
    "PublisherKeys": ".routes",
    "file_descriptor_set": ".schema",
    **dict.fromkeys(("ZenohOptions", "open_session"), ".session"),
    **dict.fromkeys(("Arrivals", "RawMessage", "SampleBatch", "Subscription"), ".subscribe"),
}


def __getattr__(name: str) -> object:
    return imported(__name__, _MODULES, name)
