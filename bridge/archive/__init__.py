"""The archive's file format: MCAP archives and raw captures, written, read and repaired."""

from bridge.archive.rawcapture import RawCaptureWriter, capture_metadata
from bridge.archive.reader import (
    ArchivedSamples,
    ArchiveReader,
    ChannelInfo,
    Damage,
    Messages,
    Record,
    describe_problem,
    read_archive,
)
from bridge.archive.repair import RepairReport, repair
from bridge.archive.writer import ArchiveWriter

__all__ = [
    "ArchiveReader",
    "ArchiveWriter",
    "ArchivedSamples",
    "ChannelInfo",
    "Damage",
    "Messages",
    "RawCaptureWriter",
    "Record",
    "RepairReport",
    "capture_metadata",
    "describe_problem",
    "read_archive",
    "repair",
]
