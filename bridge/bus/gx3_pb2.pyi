from google.protobuf import descriptor_pb2 as _descriptor_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor
ELEMENTS_FIELD_NUMBER: _ClassVar[int]
elements: _descriptor.FieldDescriptor
PHYSICAL_UNIT_FIELD_NUMBER: _ClassVar[int]
physical_unit: _descriptor.FieldDescriptor

class ImuSample(_message.Message):
    __slots__ = ("unit", "command", "timer", "ticks", "time_ns", "rx_ns", "rx_mono_raw_ns", "part_rx_mono_raw_ns", "part_lead_ns", "raw_accel", "raw_ang_rate", "accel", "stab_accel", "ang_rate", "delta_ang", "delta_vel", "mag", "stab_mag", "m", "c", "euler", "quaternion", "temperature")
    UNIT_FIELD_NUMBER: _ClassVar[int]
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    TIMER_FIELD_NUMBER: _ClassVar[int]
    TICKS_FIELD_NUMBER: _ClassVar[int]
    TIME_NS_FIELD_NUMBER: _ClassVar[int]
    RX_NS_FIELD_NUMBER: _ClassVar[int]
    RX_MONO_RAW_NS_FIELD_NUMBER: _ClassVar[int]
    PART_RX_MONO_RAW_NS_FIELD_NUMBER: _ClassVar[int]
    PART_LEAD_NS_FIELD_NUMBER: _ClassVar[int]
    RAW_ACCEL_FIELD_NUMBER: _ClassVar[int]
    RAW_ANG_RATE_FIELD_NUMBER: _ClassVar[int]
    ACCEL_FIELD_NUMBER: _ClassVar[int]
    STAB_ACCEL_FIELD_NUMBER: _ClassVar[int]
    ANG_RATE_FIELD_NUMBER: _ClassVar[int]
    DELTA_ANG_FIELD_NUMBER: _ClassVar[int]
    DELTA_VEL_FIELD_NUMBER: _ClassVar[int]
    MAG_FIELD_NUMBER: _ClassVar[int]
    STAB_MAG_FIELD_NUMBER: _ClassVar[int]
    M_FIELD_NUMBER: _ClassVar[int]
    C_FIELD_NUMBER: _ClassVar[int]
    EULER_FIELD_NUMBER: _ClassVar[int]
    QUATERNION_FIELD_NUMBER: _ClassVar[int]
    TEMPERATURE_FIELD_NUMBER: _ClassVar[int]
    unit: str
    command: int
    timer: int
    ticks: int
    time_ns: int
    rx_ns: int
    rx_mono_raw_ns: int
    part_rx_mono_raw_ns: int
    part_lead_ns: int
    raw_accel: _containers.RepeatedScalarFieldContainer[float]
    raw_ang_rate: _containers.RepeatedScalarFieldContainer[float]
    accel: _containers.RepeatedScalarFieldContainer[float]
    stab_accel: _containers.RepeatedScalarFieldContainer[float]
    ang_rate: _containers.RepeatedScalarFieldContainer[float]
    delta_ang: _containers.RepeatedScalarFieldContainer[float]
    delta_vel: _containers.RepeatedScalarFieldContainer[float]
    mag: _containers.RepeatedScalarFieldContainer[float]
    stab_mag: _containers.RepeatedScalarFieldContainer[float]
    m: _containers.RepeatedScalarFieldContainer[float]
    c: _containers.RepeatedScalarFieldContainer[float]
    euler: _containers.RepeatedScalarFieldContainer[float]
    quaternion: _containers.RepeatedScalarFieldContainer[float]
    temperature: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, unit: _Optional[str] = ..., command: _Optional[int] = ..., timer: _Optional[int] = ..., ticks: _Optional[int] = ..., time_ns: _Optional[int] = ..., rx_ns: _Optional[int] = ..., rx_mono_raw_ns: _Optional[int] = ..., part_rx_mono_raw_ns: _Optional[int] = ..., part_lead_ns: _Optional[int] = ..., raw_accel: _Optional[_Iterable[float]] = ..., raw_ang_rate: _Optional[_Iterable[float]] = ..., accel: _Optional[_Iterable[float]] = ..., stab_accel: _Optional[_Iterable[float]] = ..., ang_rate: _Optional[_Iterable[float]] = ..., delta_ang: _Optional[_Iterable[float]] = ..., delta_vel: _Optional[_Iterable[float]] = ..., mag: _Optional[_Iterable[float]] = ..., stab_mag: _Optional[_Iterable[float]] = ..., m: _Optional[_Iterable[float]] = ..., c: _Optional[_Iterable[float]] = ..., euler: _Optional[_Iterable[float]] = ..., quaternion: _Optional[_Iterable[float]] = ..., temperature: _Optional[_Iterable[int]] = ...) -> None: ...

class Status(_message.Message):
    __slots__ = ("unit", "time_ns", "connected", "state", "command", "output_rate_hz", "samples_per_s", "samples", "dropped", "checksum_failures", "implausible", "bytes_skipped", "resyncs", "reconnects", "glitches", "clock_offset_ns", "clock_drift_ppm", "clock_spread_ns", "port", "baud", "host_clock", "time_uncertainty_ns")
    class State(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        STATE_UNSPECIFIED: _ClassVar[Status.State]
        CONNECTING: _ClassVar[Status.State]
        BRINGING_UP: _ClassVar[Status.State]
        STREAMING: _ClassVar[Status.State]
        DISCONNECTED: _ClassVar[Status.State]
        STOPPED: _ClassVar[Status.State]
    STATE_UNSPECIFIED: Status.State
    CONNECTING: Status.State
    BRINGING_UP: Status.State
    STREAMING: Status.State
    DISCONNECTED: Status.State
    STOPPED: Status.State
    UNIT_FIELD_NUMBER: _ClassVar[int]
    TIME_NS_FIELD_NUMBER: _ClassVar[int]
    CONNECTED_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_PER_S_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    CHECKSUM_FAILURES_FIELD_NUMBER: _ClassVar[int]
    IMPLAUSIBLE_FIELD_NUMBER: _ClassVar[int]
    BYTES_SKIPPED_FIELD_NUMBER: _ClassVar[int]
    RESYNCS_FIELD_NUMBER: _ClassVar[int]
    RECONNECTS_FIELD_NUMBER: _ClassVar[int]
    GLITCHES_FIELD_NUMBER: _ClassVar[int]
    CLOCK_OFFSET_NS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_DRIFT_PPM_FIELD_NUMBER: _ClassVar[int]
    CLOCK_SPREAD_NS_FIELD_NUMBER: _ClassVar[int]
    PORT_FIELD_NUMBER: _ClassVar[int]
    BAUD_FIELD_NUMBER: _ClassVar[int]
    HOST_CLOCK_FIELD_NUMBER: _ClassVar[int]
    TIME_UNCERTAINTY_NS_FIELD_NUMBER: _ClassVar[int]
    unit: str
    time_ns: int
    connected: bool
    state: Status.State
    command: int
    output_rate_hz: float
    samples_per_s: float
    samples: int
    dropped: int
    checksum_failures: int
    implausible: int
    bytes_skipped: int
    resyncs: int
    reconnects: int
    glitches: int
    clock_offset_ns: int
    clock_drift_ppm: float
    clock_spread_ns: float
    port: str
    baud: int
    host_clock: HostClock
    time_uncertainty_ns: int
    def __init__(self, unit: _Optional[str] = ..., time_ns: _Optional[int] = ..., connected: _Optional[bool] = ..., state: _Optional[_Union[Status.State, str]] = ..., command: _Optional[int] = ..., output_rate_hz: _Optional[float] = ..., samples_per_s: _Optional[float] = ..., samples: _Optional[int] = ..., dropped: _Optional[int] = ..., checksum_failures: _Optional[int] = ..., implausible: _Optional[int] = ..., bytes_skipped: _Optional[int] = ..., resyncs: _Optional[int] = ..., reconnects: _Optional[int] = ..., glitches: _Optional[int] = ..., clock_offset_ns: _Optional[int] = ..., clock_drift_ppm: _Optional[float] = ..., clock_spread_ns: _Optional[float] = ..., port: _Optional[str] = ..., baud: _Optional[int] = ..., host_clock: _Optional[_Union[HostClock, _Mapping]] = ..., time_uncertainty_ns: _Optional[int] = ...) -> None: ...

class HostClock(_message.Message):
    __slots__ = ("host", "synchronised", "known", "estimated_error_ns", "maximum_error_ns", "tai_offset_s", "state", "realtime_minus_raw_ns")
    HOST_FIELD_NUMBER: _ClassVar[int]
    SYNCHRONISED_FIELD_NUMBER: _ClassVar[int]
    KNOWN_FIELD_NUMBER: _ClassVar[int]
    ESTIMATED_ERROR_NS_FIELD_NUMBER: _ClassVar[int]
    MAXIMUM_ERROR_NS_FIELD_NUMBER: _ClassVar[int]
    TAI_OFFSET_S_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    REALTIME_MINUS_RAW_NS_FIELD_NUMBER: _ClassVar[int]
    host: str
    synchronised: bool
    known: bool
    estimated_error_ns: int
    maximum_error_ns: int
    tai_offset_s: int
    state: str
    realtime_minus_raw_ns: int
    def __init__(self, host: _Optional[str] = ..., synchronised: _Optional[bool] = ..., known: _Optional[bool] = ..., estimated_error_ns: _Optional[int] = ..., maximum_error_ns: _Optional[int] = ..., tai_offset_s: _Optional[int] = ..., state: _Optional[str] = ..., realtime_minus_raw_ns: _Optional[int] = ...) -> None: ...

class Event(_message.Message):
    __slots__ = ("unit", "time_ns", "ticks", "kind", "count", "detail", "leaf", "end_time_ns", "end_ticks", "clock_change_ns")
    class Kind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
        __slots__ = ()
        KIND_UNSPECIFIED: _ClassVar[Event.Kind]
        GAP: _ClassVar[Event.Kind]
        RESET: _ClassVar[Event.Kind]
        ROLLOVER: _ClassVar[Event.Kind]
        GLITCH: _ClassVar[Event.Kind]
        RECONNECT: _ClassVar[Event.Kind]
        DISCONNECT: _ClassVar[Event.Kind]
        RESYNC: _ClassVar[Event.Kind]
        BRING_UP: _ClassVar[Event.Kind]
        COMMAND: _ClassVar[Event.Kind]
        LOST: _ClassVar[Event.Kind]
        REJECTED: _ClassVar[Event.Kind]
        SHED: _ClassVar[Event.Kind]
        DUPLICATE_UNIT: _ClassVar[Event.Kind]
        HOST_CLOCK_STEP: _ClassVar[Event.Kind]
        HOST_CLOCK_SLEW: _ClassVar[Event.Kind]
        HOST_CLOCK_OFFSET: _ClassVar[Event.Kind]
    KIND_UNSPECIFIED: Event.Kind
    GAP: Event.Kind
    RESET: Event.Kind
    ROLLOVER: Event.Kind
    GLITCH: Event.Kind
    RECONNECT: Event.Kind
    DISCONNECT: Event.Kind
    RESYNC: Event.Kind
    BRING_UP: Event.Kind
    COMMAND: Event.Kind
    LOST: Event.Kind
    REJECTED: Event.Kind
    SHED: Event.Kind
    DUPLICATE_UNIT: Event.Kind
    HOST_CLOCK_STEP: Event.Kind
    HOST_CLOCK_SLEW: Event.Kind
    HOST_CLOCK_OFFSET: Event.Kind
    UNIT_FIELD_NUMBER: _ClassVar[int]
    TIME_NS_FIELD_NUMBER: _ClassVar[int]
    TICKS_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    LEAF_FIELD_NUMBER: _ClassVar[int]
    END_TIME_NS_FIELD_NUMBER: _ClassVar[int]
    END_TICKS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_CHANGE_NS_FIELD_NUMBER: _ClassVar[int]
    unit: str
    time_ns: int
    ticks: int
    kind: Event.Kind
    count: int
    detail: str
    leaf: str
    end_time_ns: int
    end_ticks: int
    clock_change_ns: int
    def __init__(self, unit: _Optional[str] = ..., time_ns: _Optional[int] = ..., ticks: _Optional[int] = ..., kind: _Optional[_Union[Event.Kind, str]] = ..., count: _Optional[int] = ..., detail: _Optional[str] = ..., leaf: _Optional[str] = ..., end_time_ns: _Optional[int] = ..., end_ticks: _Optional[int] = ..., clock_change_ns: _Optional[int] = ...) -> None: ...

class Info(_message.Message):
    __slots__ = ("unit", "port", "baud", "model_number", "serial", "model_name", "options", "lot", "firmware", "firmware_text", "decimation", "flags", "filter_width", "mag_filter_width", "up_compensation", "north_compensation", "command", "mode", "bring_up_time_ns", "bridge_version", "allow_commands", "output_rate_hz", "link", "latency_timer_ms", "host_clock")
    UNIT_FIELD_NUMBER: _ClassVar[int]
    PORT_FIELD_NUMBER: _ClassVar[int]
    BAUD_FIELD_NUMBER: _ClassVar[int]
    MODEL_NUMBER_FIELD_NUMBER: _ClassVar[int]
    SERIAL_FIELD_NUMBER: _ClassVar[int]
    MODEL_NAME_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    LOT_FIELD_NUMBER: _ClassVar[int]
    FIRMWARE_FIELD_NUMBER: _ClassVar[int]
    FIRMWARE_TEXT_FIELD_NUMBER: _ClassVar[int]
    DECIMATION_FIELD_NUMBER: _ClassVar[int]
    FLAGS_FIELD_NUMBER: _ClassVar[int]
    FILTER_WIDTH_FIELD_NUMBER: _ClassVar[int]
    MAG_FILTER_WIDTH_FIELD_NUMBER: _ClassVar[int]
    UP_COMPENSATION_FIELD_NUMBER: _ClassVar[int]
    NORTH_COMPENSATION_FIELD_NUMBER: _ClassVar[int]
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    BRING_UP_TIME_NS_FIELD_NUMBER: _ClassVar[int]
    BRIDGE_VERSION_FIELD_NUMBER: _ClassVar[int]
    ALLOW_COMMANDS_FIELD_NUMBER: _ClassVar[int]
    OUTPUT_RATE_HZ_FIELD_NUMBER: _ClassVar[int]
    LINK_FIELD_NUMBER: _ClassVar[int]
    LATENCY_TIMER_MS_FIELD_NUMBER: _ClassVar[int]
    HOST_CLOCK_FIELD_NUMBER: _ClassVar[int]
    unit: str
    port: str
    baud: int
    model_number: str
    serial: str
    model_name: str
    options: str
    lot: str
    firmware: int
    firmware_text: str
    decimation: int
    flags: int
    filter_width: int
    mag_filter_width: int
    up_compensation: int
    north_compensation: int
    command: int
    mode: int
    bring_up_time_ns: int
    bridge_version: str
    allow_commands: bool
    output_rate_hz: float
    link: str
    latency_timer_ms: int
    host_clock: HostClock
    def __init__(self, unit: _Optional[str] = ..., port: _Optional[str] = ..., baud: _Optional[int] = ..., model_number: _Optional[str] = ..., serial: _Optional[str] = ..., model_name: _Optional[str] = ..., options: _Optional[str] = ..., lot: _Optional[str] = ..., firmware: _Optional[int] = ..., firmware_text: _Optional[str] = ..., decimation: _Optional[int] = ..., flags: _Optional[int] = ..., filter_width: _Optional[int] = ..., mag_filter_width: _Optional[int] = ..., up_compensation: _Optional[int] = ..., north_compensation: _Optional[int] = ..., command: _Optional[int] = ..., mode: _Optional[int] = ..., bring_up_time_ns: _Optional[int] = ..., bridge_version: _Optional[str] = ..., allow_commands: _Optional[bool] = ..., output_rate_hz: _Optional[float] = ..., link: _Optional[str] = ..., latency_timer_ms: _Optional[int] = ..., host_clock: _Optional[_Union[HostClock, _Mapping]] = ...) -> None: ...
