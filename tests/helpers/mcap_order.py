"""What ``mcap doctor --strict-message-order`` checks, read with mcap's own low-level reader."""

# Chunks in log-time order that never overlap, and the messages inside each chunk (and any
# outside chunks) in log-time order. The Go CLI cannot be installed here, so this stands
# in for it.

from __future__ import annotations

from pathlib import Path

from mcap.records import Chunk, Header, Message
from mcap.stream_reader import StreamReader, breakup_chunk


def header(path: Path) -> Header:
    """The file's MCAP header record (its profile and library)."""
    with path.open("rb") as f:
        first = next(iter(StreamReader(f).records))
    assert isinstance(first, Header)
    return first


def order_problems(path: Path) -> list[str]:
    """Every place where log time goes back in file order (empty: the file is in order)."""
    problems: list[str] = []
    last = -1  # log time of the last message in file order
    chunk_end = -1
    with path.open("rb") as f:
        for k, record in enumerate(StreamReader(f, emit_chunks=True).records):
            if isinstance(record, Chunk):
                if record.message_start_time < chunk_end:
                    problems.append(f"chunk at record {k} starts at {record.message_start_time}, "
                                    f"before the previous chunk ends ({chunk_end})")
                if record.message_end_time < record.message_start_time:
                    problems.append(f"chunk at record {k} ends before it starts")
                chunk_end = record.message_end_time
                inner = [r for r in breakup_chunk(record, validate_crc=True)
                         if isinstance(r, Message)]
                for m in inner:
                    if not record.message_start_time <= m.log_time <= record.message_end_time:
                        problems.append(f"chunk at record {k}: message at {m.log_time} outside "
                                        "its time range")
            elif isinstance(record, Message):
                inner = [record]
            else:
                continue
            for m in inner:
                if m.log_time < last:
                    problems.append(f"message of channel {m.channel_id} at {m.log_time} after "
                                    f"one at {last}")
                last = max(last, m.log_time)
    return problems
