"""An archive's records once read: channels, chunks skipped, each chunk's messages as columns.

A chunk's messages stay in its decompressed bytes; the columns say where each payload
lies, so that samples are decoded from rows read straight out of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Damage:
    """A chunk skipped because it is corrupt, and what the index says it held."""

    offset: int
    start_ns: int
    end_ns: int
    why: str
    lost: dict[str, int] | None  # messages per topic (None: its indexes are damaged too)


@dataclass(frozen=True)
class ChannelInfo:
    """A channel: its topic, the unit and key leaf it belongs to, and its encoding."""

    id: int
    topic: str
    unit: str
    kind: str  # the topic's last chunk: imu, status, event, info, frame, log, raw
    message_encoding: str
    schema_id: int
    schema_name: str
    metadata: dict[str, str]


@dataclass
class Block:
    """The message records of one chunk: header columns and where each payload lies."""

    data: bytes
    channel: np.ndarray
    sequence: np.ndarray
    log_time: np.ndarray
    publish_time: np.ndarray
    start: np.ndarray
    length: np.ndarray

    def __len__(self) -> int:
        return len(self.channel)

    def payloads(self, picked: np.ndarray) -> list[bytes]:
        """The payloads at indexes ``picked``, a bytes object each."""
        data = self.data
        return [data[s : s + n] for s, n in zip(self.start[picked].tolist(),
                                                self.length[picked].tolist(), strict=True)]

    def rows(self, picked: np.ndarray, width: int) -> np.ndarray:
        """(len(picked), width) bytes of the payloads at indexes ``picked``, all ``width`` long.

        Straight out of the chunk, no bytes object each.
        """
        return rows(np.frombuffer(self.data, np.uint8), self.start[picked], width)


def rows(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(len(starts), width) bytes of ``buf`` from each start: one row copy each.

    Through a view of every window of ``width`` bytes, made without
    sliding_window_view's checks.
    """
    windows = np.ndarray((max(len(buf) - width + 1, 0), width), np.uint8, buf, strides=(1, 1))
    rows: np.ndarray = windows[starts]
    return rows
