"""The live recorder: every unit on Zenoh into one archive, as units come and go.

``Recorder`` takes what arrives off Zenoh, checks it and hands it to an archive's
writer; ``Recording`` is the run of ``gx3 record`` around it (the session, the archive,
what else sees each batch). Both need Zenoh, and are imported on first use.

This package held every part of the archive before they got packages of their own:
the format (``bridge.archive``), replay and byte-log import (``bridge.ingest``),
exports (``bridge.export``) and analyses (``bridge.analysis``). The names it declared
then are still declared here, imported on first use from their new homes; new code
imports them from there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bridge._lazy import imported

if TYPE_CHECKING:
    from bridge.analysis.allan import AllanSums, NoiseFit, averaging_factors, read_off
    from bridge.analysis.magcal import IronCalibration, UnitIron, fit, read_document
    from bridge.analysis.noise import (
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
    from bridge.archive import (
        ArchivedSamples,
        ArchiveReader,
        ArchiveWriter,
        ChannelInfo,
        Damage,
        Messages,
        RawCaptureWriter,
        Record,
        RepairReport,
        capture_metadata,
        describe_problem,
        read_archive,
        repair,
    )
    from bridge.export.describe import About
    from bridge.export.ros2_bag import Ros2Written, write_ros2
    from bridge.export.tables import (
        align_table,
        event_table,
        offline_times,
        sample_table,
        write_table,
    )
    from bridge.ingest.bytelog import Imported, LogFile, import_logs, name_time, parse_start
    from bridge.ingest.replay import CapturedReads, Replayed, captures, replay
    from bridge.recorder.hosts import HostView
    from bridge.recorder.live import Recorder
    from bridge.recorder.recording import Recording
    from bridge.recorder.units import UnitRow

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
    "Recording",
    "RepairReport",
    "Replayed",
    "Ros2Written",
    "SensorNoise",
    "UnitIron",
    "UnitNoise",
    "UnitRow",
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

#: The package each name comes from, imported when the name is first asked for.
_HOMES = {
    "HostView": "bridge.recorder.hosts",
    "Recorder": "bridge.recorder.live",
    "Recording": "bridge.recorder.recording",
    "UnitRow": "bridge.recorder.units",
    **dict.fromkeys(("ArchiveReader", "ArchiveWriter", "ArchivedSamples", "ChannelInfo",
                     "Damage", "Messages", "RawCaptureWriter", "Record", "RepairReport",
                     "capture_metadata", "describe_problem", "read_archive", "repair"),
                    "bridge.archive"),
    **dict.fromkeys(("CapturedReads", "Imported", "LogFile", "Replayed", "captures",
                     "import_logs", "name_time", "parse_start", "replay"), "bridge.ingest"),
    **dict.fromkeys(("About", "Ros2Written", "align_table", "event_table", "offline_times",
                     "sample_table", "write_ros2", "write_table"), "bridge.export"),
    **dict.fromkeys(("NOISE_KEYS", "AllanSums", "IronCalibration", "NoiseFit",
                     "SensorNoise", "UnitIron", "UnitNoise", "UnitSamples",
                     "averaging_factors", "collect_samples", "fit", "kalibr_yaml",
                     "read_document", "read_off", "stretch_text", "unit_noise",
                     "units_noise"), "bridge.analysis"),
}


def __getattr__(name: str) -> object:
    return imported(__name__, _HOMES, name)
