"""The 3DM-GX3 command set as one declarative table.

Every byte layout of the manual's Command Reference lives here and nowhere else:
the encoder, the decoder, the framer, the emulator and the generated docs read it.
Field order is wire order. A quantity has one name in every layer, from the wire to the
archive (``QUANTITIES``; docs/design/protocol.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from functools import cached_property
from typing import Any

TICKS_PER_SECOND = 62_500
CALCULATION_CYCLE_S = 0.001  # the unit samples, filters and answers once per 1 ms cycle
#: From the end of a cycle (its timer, the end of its filter window) to a data record's first
#: byte on the line: the cycle's calculation (steps 2-6 of the manual's Calculation Cycle).
#: The manual gives no figure; the emulator sends after this long and the timing layer
#: takes it out, so a unit whose firmware takes longer is late by the difference, as every
#: unit of that firmware is (docs/design/time.md).
PROCESSING_DELAY_S = 0.0002
ERROR_CODE = 0x21
ERROR_REPLY = bytes((0x21, 0x00, 0x21))
BAUD_RATES = (115_200, 230_400, 460_800, 921_600)
#: The manual's Table 5: the most records a second (of 31 bytes) each baud rate carries.
MAX_OUTPUT_HZ = {115_200: 250, 230_400: 333, 460_800: 500, 921_600: 1000}
DEFAULT_BAUD = 115_200


class Mode(IntEnum):
    """Values of the 0xD4 mode selector (0 reads the current mode)."""

    ACTIVE = 1
    CONTINUOUS = 2
    IDLE = 3
    SLEEP = 4
    DEEP_SLEEP = 5


class Flag(IntEnum):
    """Bits of the 0xDB data-conditioning word; bit 12 (not 11) enables quaternions."""

    ORIENTATION = 1 << 0
    CONING_SCULLING = 1 << 1
    LITTLE_ENDIAN_FLOATS = 1 << 4
    SUPPRESS_NAN = 1 << 5
    FINITE_SIZE_CORRECTION = 1 << 6
    DISABLE_MAG = 1 << 8
    MAG_LOW_POWER = 1 << 9
    DISABLE_NORTH_COMPENSATION = 1 << 10
    DISABLE_GRAVITY_COMPENSATION = 1 << 11
    QUATERNION = 1 << 12


DEFAULT_FLAGS = Flag.ORIENTATION | Flag.CONING_SCULLING
#: The accel and gyro filter width a unit leaves the factory with (0xDB byte 9).
DEFAULT_FILTER_WIDTH = 15

#: The 0xDA self-test bits the manual names (its list is cut short after bit 3): a set
#: bit means the function is within specification.
STATIONARY_TEST_BITS = {0: "supply_3v", 3: "system_tick"}
#: The reply whose ``flags`` set the float byte order of every record after it.
BYTE_ORDER_REPLY = 0xDB

SIZES = {"u8": 1, "u16": 2, "u32": 4, "f32": 4, "ascii": 16, "pad": 1}


@dataclass(frozen=True)
class Field:
    """One wire field.

    Two kinds of bounds, for two purposes. A parameter carries the unit's rules: it
    clamps a setting into ``lo``..``hi`` and ignores one outside ``allowed`` (the
    encoder refuses both). A reply field carries what a unit can send: ``domain``
    (floats: anything non-finite too, as in idle mode or with NaN not suppressed) or
    ``domain_values``; the framer takes a candidate with anything else for garbage
    that matched the checksum. ``shape`` makes a vector or row-major matrix of
    ``kind`` elements. ``pad`` fields are reserved bytes, sent as zero, not decoded.
    ``integral``: the value is a time integral over the most recent output period (the
    manual's DeltaAngle and DeltaVelocity), so it describes that period's middle.
    """

    name: str
    kind: str
    shape: tuple[int, ...] = ()
    lo: float | None = None
    hi: float | None = None
    allowed: frozenset[int] | None = None
    domain: tuple[float, float] | None = None
    domain_values: frozenset[int] | None = None
    unit: str = ""
    doc: str = ""
    integral: bool = False

    # cached: the framer asks for these for every record it checks
    @cached_property
    def count(self) -> int:
        """Elements of ``kind`` in the field: 1 for a scalar, the product of ``shape``."""
        return math.prod(self.shape)

    @cached_property
    def size(self) -> int:
        """Bytes the field occupies on the wire."""
        return SIZES[self.kind] * self.count

    @property
    def is_pad(self) -> bool:
        """Whether the field is reserved bytes (sent as zero, never decoded)."""
        return self.kind == "pad"


def _pad(n: int) -> Field:
    """Reserved bytes: zero on the wire, never decoded."""
    return Field("reserved", "pad", (n,), doc="reserved, set to 0")


def _vec(name: str, bound: float, unit: str, doc: str, shape: tuple[int, ...] = (3,),
         integral: bool = False) -> Field:
    return Field(name, "f32", shape, domain=(-bound, bound), unit=unit, doc=doc,
                 integral=integral)


# Far beyond any sensor range (and any 17-bit raw code); random bytes read as a float
# exceed it about 43 % of the time, so a few floats make garbage implausible.
_PHYSICAL = 1e6
_UNIT = 1.001  # rotation matrix and quaternion elements, with float32 rounding
_ANGLE = math.pi + 1e-3

#: Reply fields, by the name every layer uses for them.
QUANTITIES: dict[str, Field] = {
    f.name: f
    for f in (
        # In idle mode raw codes are "undetermined": any finite value within the loose bound.
        _vec("raw_accel", _PHYSICAL, "A/D code", "raw accelerometer codes"),
        _vec("raw_ang_rate", _PHYSICAL, "A/D code", "raw gyro codes"),
        _vec("accel", _PHYSICAL, "g", "specific force, sensor frame"),
        _vec("stab_accel", _PHYSICAL, "g", "gyro-stabilised gravity estimate, sensor frame"),
        _vec("ang_rate", _PHYSICAL, "rad/s", "angular rate, sensor frame"),
        _vec("delta_ang", _PHYSICAL, "rad", "integral of ang_rate over the sample period",
             integral=True),
        _vec("delta_vel", _PHYSICAL, "g*s", "integral of accel over the sample period",
             integral=True),
        _vec("mag", _PHYSICAL, "gauss", "magnetic field, sensor frame"),
        _vec("stab_mag", _PHYSICAL, "gauss", "gyro-stabilised field estimate, sensor frame"),
        _vec("m", _UNIT, "", "orientation matrix, v_local = M v_earth (NED)", (3, 3)),
        _vec("c", _UNIT, "", "orientation update over one calculation cycle", (3, 3)),
        _vec("euler", _ANGLE, "rad", "roll, pitch, yaw (ZYX)"),
        _vec("quaternion", _UNIT, "", "q0 (scalar), q1, q2, q3; earth to sensor", (4,)),
        _vec("accel_bias", _PHYSICAL, "g", "bias subtracted from accel"),
        _vec("gyro_bias", _PHYSICAL, "rad/s", "bias subtracted from ang_rate"),
        Field("temperature", "u16", (4,), domain=(0, 4095), unit="A/D code",
              doc="mag, gyro Y/accel X, gyro X/accel Z,Y, gyro Z (12-bit)"),
        Field("timer", "u32", unit="tick", doc="62,500 ticks per second, unsigned, wraps"),
        Field("command", "u8", doc="continuous command byte (0: none)"),
        Field("quantity", "u16", doc="1 accel bias, 2 gyro bias, 0xFFFF none"),
        Field("mode", "u8", domain=(1, 5), doc="1 active, 2 continuous, 3 idle, 4 sleep, 5 deep"),
        Field("mode_preset", "u8", domain=(1, 3), doc="mode entered on power-up or wake"),
        Field("continuous_preset", "u8", doc="data command used in continuous mode (0: none)"),
        Field("port", "u8", domain=(1, 3), doc="1 UART1 (host), 2 and 3 unused on the GX3-25"),
        Field("baud", "u32", domain_values=frozenset({0, *BAUD_RATES}), unit="bit/s",
              doc="0 for the unused ports 2 and 3"),
        Field("config", "u8", doc="bit 1: UART enabled"),
        Field("test_result", "u32", doc="stationary self-test flags, set bit = in spec"),
        Field("decimation", "u16", domain=(1, 1000), doc="output rate = 1000 Hz / decimation"),
        Field("flags", "u16", doc="data-conditioning bits (see Flag)"),
        Field("filter_width", "u8", domain=(1, 32), doc="gyro/accel moving-average width"),
        Field("mag_filter_width", "u8", domain=(1, 32), doc="magnetometer moving-average width"),
        Field("up_compensation", "u16", domain=(0, 1000), unit="s",
              doc="gravity correction (0 from firmware before 1.1.27)"),
        Field("north_compensation", "u16", domain=(0, 1000), unit="s",
              doc="north correction (0 from firmware before 1.1.27)"),
        Field("word", "u16", doc="EEPROM word"),
        Field("firmware", "u32", doc="firmware version number"),
        Field("selector", "u8", doc="device ID string selector echoed (0xFF: unknown)"),
        Field("text", "ascii", doc="16-character ASCII ID string"),
    )
}


def _q(*names: str) -> tuple[Field, ...]:
    """Reply fields by quantity name."""
    return tuple(QUANTITIES[n] for n in names)


#: Firmware version numbers as 0xE9 reports them: 1127 is 1.1.27.
FIRMWARE_1_1_27 = 1127


@dataclass(frozen=True)
class When:
    """A condition on one parameter: its value is in ``values`` (``param`` None: always).

    ``before_firmware`` limits it to firmware older than that version number; with the
    firmware unknown it holds, the stricter assumption.
    """

    param: str | None = None
    values: frozenset[int] = frozenset()
    before_firmware: int | None = None

    def holds(self, params: dict[str, Any], firmware: int | None = None) -> bool:
        """Whether the condition holds for a command sent with ``params``.

        Args:
            params: The command's parameters by name.
            firmware: The unit's 0xE9 version number (1127 for 1.1.27); None: unknown.

        Returns:
            True when ``param`` has one of ``values`` (or there is no ``param``) and the
            firmware is older than ``before_firmware`` or not known.
        """
        if (self.before_firmware is not None and firmware is not None
                and firmware >= self.before_firmware):
            return False
        return self.param is None or params.get(self.param) in self.values


ALWAYS = (When(),)


def _when(param: str, *values: int, before_firmware: int | None = None) -> When:
    return When(param, frozenset(values), before_firmware)


@dataclass(frozen=True)
class Command:
    """One command of the Command Set Summary.

    ``confirm`` are the fixed bytes after the command byte; a unit answers a
    mismatch with the error reply. ``reply`` is ``None`` for commands that never
    answer. ``persists_when``: any of these makes it write non-volatile memory;
    ``silent_when``: the unit does not reply; ``ignored_when``: the unit ignores the
    parameters named in ``ignored``, so they may be left out (sent as 0).
    """

    code: int
    name: str
    title: str
    confirm: bytes = b""
    params: tuple[Field, ...] = ()
    reply: tuple[Field, ...] | None = ()
    data: bool = False
    persists_when: tuple[When, ...] = ()
    silent_when: When | None = None
    ignored_when: When | None = None
    ignored: tuple[str, ...] = ()
    documented: bool = True
    notes: str = ""

    @cached_property
    def length(self) -> int:
        """Bytes the host sends."""
        return 1 + len(self.confirm) + sum(f.size for f in self.params)

    @cached_property
    def reply_length(self) -> int | None:
        """Bytes of the reply: echo byte, fields, 16-bit checksum."""
        if self.reply is None:
            return None
        return 3 + sum(f.size for f in self.reply)

    def changes_nonvolatile(self, params: dict[str, Any], firmware: int | None = None) -> bool:
        """Whether sending this with ``params`` writes the unit's non-volatile memory.

        Args:
            params: The parameters it would be sent with, by name.
            firmware: The 0xE9 version number (1127 for 1.1.27); unknown (None) assumes
                the older, stricter rules.

        Returns:
            True if any rule of ``persists_when`` holds.
        """
        return any(rule.holds(params, firmware) for rule in self.persists_when)

    def replies(self, params: dict[str, Any]) -> bool:
        """Whether the unit answers this command sent with ``params``.

        Args:
            params: The parameters it is sent with, by name.

        Returns:
            False for a command that never answers, or one sent the way that silences
            it (``silent_when``, such as 0xDB function 3).
        """
        if self.reply is None:
            return False
        return self.silent_when is None or not self.silent_when.holds(params)

    def ignores(self, params: dict[str, Any]) -> tuple[str, ...]:
        """The parameters the unit ignores when sent with ``params``.

        Args:
            params: The parameters it is sent with, by name.

        Returns:
            The names in ``ignored`` when ``ignored_when`` holds (a read), else none.
        """
        if self.ignored_when is not None and self.ignored_when.holds(params):
            return self.ignored
        return ()


_DATA = (
    (0xC1, "raw_accel_ang_rate", "Raw Accelerometer and Angular Rate Sensor Outputs",
     ("raw_accel", "raw_ang_rate")),
    (0xC2, "accel_ang_rate", "Acceleration & Angular Rate", ("accel", "ang_rate")),
    (0xC3, "delta_ang_vel", "DeltaAngle & DeltaVelocity", ("delta_ang", "delta_vel")),
    (0xC5, "orientation", "Orientation Matrix", ("m",)),
    (0xC6, "orientation_update", "Orientation Update Matrix", ("c",)),
    (0xC7, "mag", "Scaled Magnetometer Vector", ("mag",)),
    (0xC8, "accel_ang_rate_orientation", "Acceleration, Angular Rate & Orientation Matrix",
     ("accel", "ang_rate", "m")),
    (0xCB, "accel_ang_rate_mag", "Acceleration, Angular Rate & Magnetometer Vector",
     ("accel", "ang_rate", "mag")),
    (0xCC, "accel_ang_rate_mag_orientation",
     "Acceleration, Angular Rate & Magnetometer Vectors & Orientation Matrix",
     ("accel", "ang_rate", "mag", "m")),
    (0xCE, "euler", "Euler Angles", ("euler",)),
    (0xCF, "euler_ang_rate", "Euler Angles and Angular Rates", ("euler", "ang_rate")),
    (0xD1, "temperatures", "Temperatures", ("temperature",)),
    (0xD2, "stab_accel_ang_rate_mag", "Gyro Stabilized Acceleration, Angular Rate & Magnetometer",
     ("stab_accel", "ang_rate", "stab_mag")),
    (0xD3, "delta_ang_vel_mag", "DeltaAngle & DeltaVelocity & Magnetometer Vectors",
     ("delta_ang", "delta_vel", "mag")),
    (0xDF, "quaternion", "Quaternion", ("quaternion",)),
)

DATA_CODES: frozenset[int] = frozenset(code for code, *_ in _DATA)
_CONTINUOUS_ALLOWED = frozenset({0}) | DATA_CODES
_SETTINGS_READ = _when("function", 0)
_FUNCTION_RW = frozenset({0, 1, 2})
_REALIGN = frozenset(range(1, 101)) | {255}


def _u8(name: str, allowed: frozenset[int] | None = None, lo: int | None = None,
        hi: int | None = None, doc: str = "") -> Field:
    return Field(name, "u8", (), lo, hi, allowed, doc=doc)


def _u16(name: str, lo: int | None = None, hi: int | None = None, doc: str = "",
         allowed: frozenset[int] | None = None) -> Field:
    return Field(name, "u16", (), lo, hi, allowed, doc=doc)


_SETTINGS: tuple[Command, ...] = (
    Command(0xC4, "set_continuous", "Set Continuous Mode", b"\xc1\x29",
            (_u8("command", _CONTINUOUS_ALLOWED, doc="data command to stream, 0 stops"),),
            _q("command", "timer"),
            notes="Does not change the continuous preset."),
    Command(0xC9, "write_accel_bias", "Write Accel Bias Correction", b"\xb7\x44",
            (Field("accel_bias", "f32", (3,), unit="g"),), _q("accel_bias", "timer")),
    Command(0xCA, "write_gyro_bias", "Write Gyro Bias Correction", b"\x12\xa5",
            (Field("gyro_bias", "f32", (3,), unit="rad/s"),), _q("gyro_bias", "timer")),
    Command(0xCD, "capture_gyro_bias", "Capture Gyro Bias", b"\xc1\x29",
            (_u16("sampling_time_ms", 0, 65_535, "stationary averaging, 10000-30000 advised"),),
            _q("gyro_bias", "timer"),
            notes="The reply comes after the sampling time has elapsed."),
    Command(0xD0, "transfer_to_nonvolatile", "Transfer Quantity to Non-Volatile Memory",
            b"\xc1\x29",
            (_u16("quantity", doc="1 accel bias, 2 gyro bias", allowed=frozenset({1, 2})),),
            _q("quantity", "timer"), persists_when=(_when("quantity", 1, 2),),
            notes="Any other quantity does nothing and is answered with 0xFFFF."),
    Command(0xD4, "mode", "Mode", b"\xa3\x47",
            (_u8("mode", frozenset(range(6)), doc="0 read, 1 active, 2 continuous, 3 idle, "
                 "4 sleep, 5 deep sleep"),),
            _q("mode"),
            notes="Entering continuous mode sends this reply before the first record."),
    Command(0xD5, "mode_preset", "Mode Preset", b"\xba\x89",
            (_u8("mode_preset", frozenset(range(4)), doc="0 read, 1 active, 2 continuous, "
                 "3 idle"),),
            _q("mode_preset"), persists_when=(_when("mode_preset", 1, 2, 3),),
            notes="0 reads the preset and stores nothing."),
    Command(0xD6, "continuous_preset", "Continuous Preset", b"\xc6\x6b",
            (_u8("continuous_preset", _CONTINUOUS_ALLOWED, doc="data command, 0 reads"),),
            _q("continuous_preset"), persists_when=(_when("continuous_preset", *DATA_CODES),),
            notes="0 or a non-data command stores nothing and returns the stored value."),
    Command(0xD7, "timer", "Timer", b"\xc1\x29",
            (_u8("function", frozenset({0, 1, 2}), doc="0 read, 1 set timer, 2 set PPS seconds"),
             Field("value", "u32", doc="new timer or PPS value")),
            _q("timer"), ignored_when=_SETTINGS_READ, ignored=("value",)),
    Command(0xD9, "comms_settings", "Communications Settings", b"\xc3\x55",
            (_u8("port", frozenset({1, 2, 3}), doc="1 UART1"),
             _u8("function", _FUNCTION_RW, doc="0 read, 1 set, 2 set and store"),
             Field("baud", "u32", allowed=frozenset(BAUD_RATES), unit="bit/s"),
             _u8("config", doc="bit 1: UART enabled (UART1 cannot be disabled)"),
             _pad(1)),
            (QUANTITIES["port"], QUANTITIES["baud"], QUANTITIES["config"], _pad(1)),
            persists_when=(_when("function", 2),),
            ignored_when=_SETTINGS_READ, ignored=("baud", "config"),
            notes="The reply is sent at the old rate; the new rate applies after it. "
                  "Ports 2 and 3 reply with baud 0."),
    Command(0xDA, "stationary_test", "Stationary Test", b"", (), _q("test_result")),
    Command(0xDB, "sampling_settings", "Sampling Settings", b"\xa8\xb9",
            (_u8("function", frozenset({0, 1, 2, 3}), doc="0 read, 1 set, 2 set and store, "
                 "3 set without reply"),
             _u16("decimation", 1, 1000, "output rate = 1000 Hz / decimation"),
             _u16("flags", doc="data-conditioning bits"),
             _u8("filter_width", lo=1, hi=32, doc="gyro/accel filter width, default 15"),
             _u8("mag_filter_width", lo=1, hi=32, doc="mag filter width, default 17"),
             _u16("up_compensation", 1, 1000, "seconds, default 10"),
             _u16("north_compensation", 1, 1000, "seconds, default 10"),
             _pad(6)),
            (*_q("decimation", "flags", "filter_width", "mag_filter_width", "up_compensation",
                "north_compensation"), _pad(6)),
            persists_when=(_when("function", 2),
                           _when("function", 1, before_firmware=FIRMWARE_1_1_27)),
            silent_when=_when("function", 3), ignored_when=_SETTINGS_READ,
            ignored=("decimation", "flags", "filter_width", "mag_filter_width",
                     "up_compensation", "north_compensation"),
            notes="Firmware before 1.1.27 stores with function 1 too, and replies 0 for "
                  "the compensations."),
    Command(0xDD, "realign_up_north", "Realign Up and North", b"\x54\x4c",
            (_u8("function", frozenset({0, 3}), doc="0 realign, 3 realign without reply"),
             _u8("up_realign", _REALIGN, doc="1-100 tenths of a second, 255 skip"),
             _u8("north_realign", _REALIGN, doc="1-100 tenths of a second, 255 skip"),
             _pad(4)),
            (_pad(4),), silent_when=_when("function", 3),
            notes="The 4 reply bytes are undetermined; they are not decoded."),
    Command(0xE4, "write_eeprom", "Write Word to EEPROM", b"\xc1\x29\x00",
            (_u16("address", doc="user words 0x0000-0x00EF and 0x0400-0x042F"),
             _u16("value")),
            _q("word"), persists_when=ALWAYS,
            notes="The fixed 0x00 after the confirmation is checked like it."),
    Command(0xE5, "read_eeprom", "Read Word from EEPROM", b"\x00",
            (_u16("address", doc="user words 0x0000-0x00EF and 0x0400-0x042F"),),
            _q("word"), notes="The fixed 0x00 is checked like a confirmation byte."),
    Command(0xE9, "firmware_version", "Read Firmware Version Number", b"", (), _q("firmware")),
    Command(0xEA, "device_id", "Read Device ID String", b"",
            (_u8("selector", frozenset(range(5)), doc="0 model number, 1 serial, 2 model name, "
                 "3 options, 4 lot"),),
            _q("selector", "text")),
    Command(0xFA, "stop_continuous", "Stop Continuous Mode", b"\x75\xb4", (), None),
    Command(0xFD, "firmware_update", "Firmware Update", b"", (), None, persists_when=ALWAYS,
            documented=False,
            notes="The manual gives no layout; it is listed, never encoded."),
    Command(0xFE, "device_reset", "Device Reset", b"\x9e\x3a", (), None, persists_when=ALWAYS,
            notes="Listed as state-changing: a reset loses every volatile setting."),
)

COMMANDS: dict[int, Command] = {
    c.code: c
    for c in sorted(
        (*(Command(code, name, title, reply=(*_q(*fields), QUANTITIES["timer"]), data=True)
           for code, name, title, fields in _DATA),
         *_SETTINGS),
        key=lambda c: c.code,
    )
}
BY_NAME: dict[str, Command] = {c.name: c for c in COMMANDS.values()}


@dataclass(frozen=True)
class ReplySpec:
    """What the framer and decoder need of a reply."""

    code: int
    name: str
    fields: tuple[Field, ...] = field(default=())

    @cached_property
    def length(self) -> int:
        """Bytes of the reply: echo byte, fields, 16-bit checksum."""
        return 3 + sum(f.size for f in self.fields)

    @cached_property
    def integral(self) -> bool:
        """Whether its values are integrals over the output period (0xC3, 0xD3).

        They describe the middle of that period, half a period before an instantaneous
        record's values; a record's ``time_ns`` is the instant they describe.
        """
        return any(f.integral for f in self.fields)

    def offset(self, name: str) -> int:
        """Byte position of a field in the reply (the echo byte is at 0).

        Args:
            name: The field's name.

        Returns:
            Where its first byte is.

        Raises:
            KeyError: The reply has no such field.
        """
        at = 1
        for f in self.fields:
            if f.name == name:
                return at
            at += f.size
        raise KeyError(f"0x{self.code:02X} {self.name} has no field {name!r}")


#: Every reply a unit can send, by its first byte: the echoed command, or 0x21.
REPLIES: dict[int, ReplySpec] = {
    ERROR_CODE: ReplySpec(ERROR_CODE, "error"),
    **{c.code: ReplySpec(c.code, c.name, c.reply)
       for c in COMMANDS.values() if c.reply is not None},
}


def lookup(command: int | str) -> Command:
    """Find a command by code or name.

    Args:
        command: Its code (0xDB) or its name ("sampling_settings").

    Returns:
        The command.

    Raises:
        KeyError: No such command; the message lists every one that exists.
    """
    found = COMMANDS.get(command) if isinstance(command, int) else BY_NAME.get(command)
    if found is None:
        shown = f"0x{command:02X}" if isinstance(command, int) else repr(command)
        raise KeyError(f"unknown 3DM-GX3 command {shown}; known: "
                       + ", ".join(f"0x{c:02X} {cmd.name}" for c, cmd in COMMANDS.items()))
    return found
