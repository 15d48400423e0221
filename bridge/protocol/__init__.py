"""The 3DM-GX3 protocol: command table, codec, framer and conversions, with no I/O.

Everything here works on the bytes and arrays it is handed: nothing opens a port, reads
a clock or imports Zenoh, so one code path serves a live bridge, a replay, the emulator
and your own program. ``table`` declares every command and reply of the manual once;
``codec`` encodes commands and replies and decodes replies a block at a time; ``framer``
finds whole replies in a byte stream cut anywhere; ``convert`` holds the manual's unit
and orientation conversions; ``docs`` renders the table as the reference. Why it is
built so: docs/design/protocol.md.

```python
from bridge.protocol import Framer, encode_command

port.write(encode_command("sampling_settings", function=0))
framer = Framer(expect={0xDB, 0xC2})
for batch in framer.feed(port.read(4096), time.time_ns()):
    batch["accel"], batch["timer"], batch.rx_ns
```
"""

from bridge.protocol.codec import (
    Batch,
    ParsedCommand,
    Records,
    checksum,
    command_length,
    decode_block,
    encode_command,
    encode_replies,
    encode_reply,
    parse_command,
    plausible,
    reply_dtype,
)
from bridge.protocol.convert import (
    STANDARD_GRAVITY,
    celsius_to_mag_temperature_code,
    euler_to_m,
    euler_to_quaternion,
    fir_response,
    local_gravity,
    m_to_euler,
    m_to_quaternion,
    mag_fir_response,
    mag_fir_response_simplified,
    mag_low_power_fir_response,
    mag_temperature_celsius,
    mag_temperature_celsius_linear,
    quaternion_to_euler,
    quaternion_to_m,
    sensor_to_earth_xyzw,
    ticks_to_seconds,
    wake_time_seconds,
)
from bridge.protocol.docs import command_table_markdown, reply_schemas
from bridge.protocol.framer import Framer, FramerStats, other_byte_order
from bridge.protocol.table import (
    BAUD_RATES,
    CALCULATION_CYCLE_S,
    COMMANDS,
    DATA_CODES,
    DEFAULT_BAUD,
    ERROR_REPLY,
    QUANTITIES,
    REPLIES,
    TICKS_PER_SECOND,
    Command,
    Field,
    Flag,
    Mode,
    ReplySpec,
    When,
    lookup,
)

__all__ = [
    "BAUD_RATES",
    "CALCULATION_CYCLE_S",
    "COMMANDS",
    "DATA_CODES",
    "DEFAULT_BAUD",
    "ERROR_REPLY",
    "QUANTITIES",
    "REPLIES",
    "STANDARD_GRAVITY",
    "TICKS_PER_SECOND",
    "Batch",
    "Command",
    "Field",
    "Flag",
    "Framer",
    "FramerStats",
    "Mode",
    "ParsedCommand",
    "Records",
    "ReplySpec",
    "When",
    "celsius_to_mag_temperature_code",
    "checksum",
    "command_length",
    "command_table_markdown",
    "decode_block",
    "encode_command",
    "encode_replies",
    "encode_reply",
    "euler_to_m",
    "euler_to_quaternion",
    "fir_response",
    "local_gravity",
    "lookup",
    "m_to_euler",
    "m_to_quaternion",
    "mag_fir_response",
    "mag_fir_response_simplified",
    "mag_low_power_fir_response",
    "mag_temperature_celsius",
    "mag_temperature_celsius_linear",
    "other_byte_order",
    "parse_command",
    "plausible",
    "quaternion_to_euler",
    "quaternion_to_m",
    "reply_dtype",
    "reply_schemas",
    "sensor_to_earth_xyzw",
    "ticks_to_seconds",
    "wake_time_seconds",
]
