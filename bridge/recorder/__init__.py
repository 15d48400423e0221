"""Archives: the fleet recorded into MCAP, and read, replayed, exported and repaired.

An archive is one MCAP file (or numbered parts) that holds the very messages the
bridges publish on Zenoh, in log-time order, with frames and an event log for viewers.
A raw capture holds the bytes a bridge read from its unit and when each read came, so
that a replay gives what the live bridge gave. Reading never gives up on a damaged or
unfinished file: what is readable is read, and what is not is said. The layouts of
archives, raw captures and exports: ``docs/design/archive.md``.

The live recorder (``Recorder``, ``HostView``: Zenoh) and the table export
(``sample_table`` and the rest: pyarrow) are imported on first use, so that reading or
writing an archive needs neither.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported
from bridge.recorder.allan import AllanSums, NoiseFit, averaging_factors, read_off
from bridge.recorder.bytelog import Imported, LogFile, import_logs, name_time, parse_start
from bridge.recorder.describe import About
from bridge.recorder.magcal import IronCalibration, UnitIron, fit, read_document
from bridge.recorder.noise import (
    NOISE_KEYS,
    SensorNoise,
    UnitNoise,
    UnitSamples,
    collect_samples,
    kalibr_yaml,
    stretch_text,
    unit_noise,
    units_noise,
)
from bridge.recorder.rawcapture import RawCaptureWriter, capture_metadata
from bridge.recorder.reader import (
    ArchivedSamples,
    ArchiveReader,
    ChannelInfo,
    Damage,
    Messages,
    Record,
    describe_problem,
    read_archive,
)
from bridge.recorder.repair import RepairReport, repair
from bridge.recorder.replay import CapturedReads, Replayed, captures, replay
from bridge.recorder.ros2_export import Ros2Written, write_ros2
from bridge.recorder.writer import ArchiveWriter

if TYPE_CHECKING:
    from bridge.recorder.live import HostView, Recorder
    from bridge.recorder.tables import (
        align_table,
        event_table,
        offline_times,
        sample_table,
        write_table,
    )

__all__ = [
    "NOISE_KEYS",
    "About",
    "AllanSums",
    "ArchiveReader",
    "ArchiveWriter",
    "ArchivedSamples",
    "CapturedReads",
    "ChannelInfo",
    "Damage",
    "HostView",
    "Imported",
    "IronCalibration",
    "LogFile",
    "Messages",
    "NoiseFit",
    "RawCaptureWriter",
    "Record",
    "Recorder",
    "RepairReport",
    "Replayed",
    "Ros2Written",
    "SensorNoise",
    "UnitIron",
    "UnitNoise",
    "UnitSamples",
    "align_table",
    "averaging_factors",
    "capture_metadata",
    "captures",
    "collect_samples",
    "describe_problem",
    "event_table",
    "fit",
    "import_logs",
    "kalibr_yaml",
    "name_time",
    "offline_times",
    "parse_start",
    "read_archive",
    "read_document",
    "read_off",
    "repair",
    "replay",
    "sample_table",
    "stretch_text",
    "unit_noise",
    "units_noise",
    "write_ros2",
    "write_table",
]

#: Names whose modules have heavy imports of their own, imported on first use.
_ON_FIRST_USE = {
    "align_table": "bridge.recorder.tables",
    "event_table": "bridge.recorder.tables",
    "offline_times": "bridge.recorder.tables",
    "sample_table": "bridge.recorder.tables",
    "write_table": "bridge.recorder.tables",
    "HostView": "bridge.recorder.live",
    "Recorder": "bridge.recorder.live",
}


def __getattr__(name: str) -> object:
    return imported(__name__, _ON_FIRST_USE, name)
