"""`gx3 decode`: raw bytes in, one JSON object per record out."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated, BinaryIO, TextIO

import typer
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

from bridge.cli.common import app, err, fail, parse_reply_code
from bridge.protocol.codec import Batch, json_safe
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES

_READ_SIZE = 1 << 20


def _open_input(path: str) -> BinaryIO:
    if path == "-":
        return sys.stdin.buffer
    try:
        return Path(path).open("rb")
    except FileNotFoundError:
        raise fail(f"{path}: no such file; give a capture of raw bytes, or - for stdin") from None
    except IsADirectoryError:
        raise fail(f"{path} is a directory; give a file of raw bytes") from None
    except PermissionError:
        raise fail(f"{path}: permission denied") from None


@app.command()
def decode(
    file: Annotated[str, typer.Argument(
        help="File of raw bytes as read off the line; - for stdin.")],
    little_endian: Annotated[bool, typer.Option(
        "--little-endian", help="Floats were sent little-endian (0xDB flag bit 4 set).")] = False,
    expect: Annotated[list[str] | None, typer.Option(
        "--expect", "-e", metavar="CODE",
        help="Reply code to look for, e.g. 0xC8 or 0xD4 (repeatable). "
             "Default: every data record.")] = None,
) -> None:
    """Decode a raw capture: one JSON object per record on stdout, a summary on stderr.

    Each object has "command" (integer), "timer" where the record has one, and
    each quantity under its name (accel, ang_rate, mag, m, euler, quaternion,
    temperature, …: see docs/commands.md); vectors and matrices are nested
    lists, matrices row-major. NaN is written as null. Corrupt bytes are
    skipped and counted; every intact record after them is still decoded.
    On a terminal, progress is shown on stderr.
    """
    codes = [parse_reply_code(c) for c in expect] if expect else sorted(DATA_CODES)
    framer = Framer(codes, little_endian=little_endian)
    out = sys.stdout
    stream = _open_input(file)
    size = None if file == "-" else os.fstat(stream.fileno()).st_size
    progress = Progress(TextColumn("decoding"), BarColumn(), DownloadColumn(),
                        TransferSpeedColumn(), console=err, transient=True,
                        disable=not err.is_terminal)
    try:
        with stream, progress:
            task = progress.add_task("decode", total=size)
            while chunk := stream.read(_READ_SIZE):
                _write(framer.feed(chunk), out)
                progress.advance(task, len(chunk))
            _write(framer.flush(), out)
        out.flush()
    except BrokenPipeError:
        sys.stderr.close()
        raise typer.Exit(0) from None
    err.print(framer.stats.summary())


def _write(batches: list[Batch], out: TextIO) -> None:
    for batch in batches:
        for record in batch.records():
            out.write(json.dumps({k: json_safe(v) for k, v in record.items()}) + "\n")
