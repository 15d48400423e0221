"""The archive's file format: MCAP archives and raw captures, written, read and repaired."""

from bridge.archive.explain import describe_problem
from bridge.archive.rawcapture import RawCaptureWriter, capture_metadata
from bridge.archive.reader import ArchiveReader, Messages, Record
from bridge.archive.records import ChannelInfo, Damage
from bridge.archive.repair import RepairReport, repair
from bridge.archive.samples import ArchivedSamples
from bridge.archive.walk import read_archive, read_samples_archive
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
    "read_samples_archive",
    "repair",
]
