"""The compiled core of a live read, or None where it is not built.

Two modules: the per-record byte work (``bridge/_records.c``, ``records``) and reading
a port until a record is whole (``bridge/_gather.c``, ``reader``).

Both are built with the package when a C compiler and Python's headers are at hand,
and skipped otherwise: every caller then runs its pure-Python path, which gives the
same records and bytes (tests/test_native.py). ``GX3_NATIVE=0`` in the environment
runs the pure-Python paths on purpose (to compare the two, or to rule the core out).
"""

from __future__ import annotations

import importlib
import os
from typing import Any, Protocol, cast


class Core(Protocol):
    """What ``bridge/_records.c`` offers (its docstrings say more)."""

    def intact(self, buf: bytes | bytearray | memoryview, start: int, size: int, code: int,
               limit: int, checks: bytes, /) -> int:
        """How many records in a row from ``start`` are whole, summed and plausible."""

    def messages(self, template: bytes, moves: bytes, at: tuple[int, ...],
                 wire: list[bytes], times: tuple[list[int], ...], /
                 ) -> tuple[list[bytes], list[bytes]]:
        """Each wire record's message and its CRC-32 seal.

        Each list of ``times`` goes at its position in ``at``.
        """


class Reader(Protocol):
    """What ``bridge/_gather.c`` offers."""

    def gather(self, fd: int, need: int, wait_s: float, /
               ) -> tuple[list[bytes], list[int], list[int], bool]:
        """Reads until ``need`` bytes came or ``wait_s`` passed.

        Returns their bytes, their receive times on the raw monotonic and the realtime
        clock, and whether the other end was gone.
        """


def _load(name: str) -> Any:
    if os.environ.get("GX3_NATIVE", "1") == "0":
        return None
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


records = cast(Core | None, _load("bridge._records"))
reader = cast(Reader | None, _load("bridge._gather"))
