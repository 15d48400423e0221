"""The archive's file format: MCAP archives and raw captures, written, read and repaired."""

from bridge.archive.explain import describe_problem
from bridge.archive.rawcapture import RawCaptureWriter, capture_metadata
from bridge.archive.reader import ArchiveReader, Messages, Record
from bridge.archive.records import ChannelInfo, Damage
from bridge.archive.repair import RepairReport, repair
from bridge.archive.samples import ArchivedSamples
from bridge.archive.times import TimeBound, TimeSpan, parse_time
from bridge.archive.walk import SampleSpan, read_archive, read_samples_archive, sample_span
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
    "SampleSpan",
    "TimeBound",
    "TimeSpan",
    "capture_metadata",
    "describe_problem",
    "parse_time",
    "read_archive",
    "read_samples_archive",
    "repair",
    "sample_span",
]
