"""Bytes into archives: raw captures replayed, and byte logs imported with no receive times."""

from bridge.ingest.bytelog import Imported, LogFile, import_logs, name_time, parse_start
from bridge.ingest.replay import CapturedReads, Replayed, captures, replay

__all__ = [
    "CapturedReads",
    "Imported",
    "LogFile",
    "Replayed",
    "captures",
    "import_logs",
    "name_time",
    "parse_start",
    "replay",
]
