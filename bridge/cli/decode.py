"""`gx3 decode`: raw bytes in, one JSON object per record out."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, BinaryIO

import numpy as np
import orjson
import typer
from rich.progress import BarColumn, DownloadColumn, Progress, TextColumn, TransferSpeedColumn

from bridge.cli.common import INTERRUPTED, app, err, fail, reply_code
from bridge.protocol.codec import Batch
from bridge.protocol.framer import Framer, other_byte_order
from bridge.protocol.table import BYTE_ORDER_REPLY, DATA_CODES

_READ_SIZE = 1 << 20  # at most; a pipe gives what it holds, so records leave as they arrive
_KEPT = 1 << 22  # input kept to try the other byte order when nothing decodes


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
        metavar="FILE", help="File of raw bytes as read off the line; - for stdin.")],
    little_endian: Annotated[bool, typer.Option(
        "--little-endian", help="Floats start little-endian (0xDB flag bit 4 set); 0xDB "
        "replies in the capture switch the order from there on.")] = False,
    expect: Annotated[list[str] | None, typer.Option(
        "--expect", "-e", metavar="CODE",
        help="Reply code to look for, e.g. 0xC8 or 0xD4 (repeatable). "
             "Default: every data record. 0xDB replies are always looked for.")] = None,
) -> None:
    """Decode a raw capture: one JSON object per record on stdout, a summary on stderr.

    Each object has "command" (integer), then each field of the record under its
    name (accel, ang_rate, mag, m, euler, quaternion, temperature, …: see
    docs/commands.md) and "timer" where the record has one; vectors and matrices
    are nested lists, matrices row-major. NaN and infinities are written as null.
    Corrupt bytes are skipped and counted; every intact record after them is still
    decoded. From a pipe, records are written as they arrive.

    An MCAP capture (a bridge's --capture file, or an archive recorded with --raw) is
    decoded unit by unit from its raw reads, each object led by "unit"; a summary line
    per unit. Exit status 1 when no record decodes (an empty input included), 2 when
    the input cannot be read, 130 on Ctrl-C, which ends it quietly, with the summary so
    far (in a pipe from a serial reader, Ctrl-C is how the user stops both).
    """
    from bridge.archive.walk import is_mcap  # loaded as decode runs, not by every command

    codes = {*([reply_code("--expect", c) for c in expect] if expect else DATA_CODES),
             BYTE_ORDER_REPLY}
    if file != "-" and is_mcap(Path(file)):
        _decode_capture(Path(file), codes, little_endian)
        return
    framer = Framer(codes, little_endian=little_endian)
    stream = _open_input(file)
    fd = stream.fileno()
    size = None if file == "-" else os.fstat(fd).st_size
    out = sys.stdout.buffer
    kept = bytearray()
    progress = Progress(TextColumn("decoding"), BarColumn(), DownloadColumn(),
                        TransferSpeedColumn(), console=err, transient=True,
                        disable=not err.is_terminal)
    try:
        with stream, progress:
            task = progress.add_task("decode", total=size)
            while chunk := os.read(fd, _READ_SIZE):
                if len(kept) < _KEPT:
                    kept += chunk[: _KEPT - len(kept)]
                out.write(_lines(framer.feed(chunk)))
                out.flush()
                progress.advance(task, len(chunk))
            out.write(_lines(framer.flush()))
            out.flush()
    except KeyboardInterrupt:  # the user's choice, not an error: the summary so far, quietly
        err.print(framer.stats.summary())
        raise typer.Exit(INTERRUPTED) from None
    except BrokenPipeError:
        sys.stderr.close()
        raise typer.Exit(0) from None
    stats = framer.stats
    err.print(stats.summary())
    if not stats.records:
        raise fail(_nothing_decoded(bytes(kept), codes, little_endian), 1)


def _decode_capture(path: Path, codes: set[int], little_endian: bool) -> None:
    """Each unit's raw reads in an MCAP capture, decoded as the bytes off its line."""
    from bridge.ingest.replay import captures

    found = 0
    unit, framer = "", None
    try:
        for reads in captures(path):
            unit, framer = reads.unit, Framer(codes, little_endian=little_endian)
            lead = f'{{"unit":{orjson.dumps(reads.unit).decode()},'.encode()
            for data in reads.data:
                sys.stdout.buffer.write(_lines(framer.feed(data), lead))
            sys.stdout.buffer.write(_lines(framer.flush(), lead))
            sys.stdout.buffer.flush()
            err.print(f"{unit}: {framer.stats.summary()}")
            found += sum(framer.stats.records.values())
            framer = None  # said: not again if the next unit is interrupted
    except KeyboardInterrupt:  # as from a pipe: the unit's summary so far, quietly
        if framer is not None:
            err.print(f"{unit}: {framer.stats.summary()}")
        raise typer.Exit(INTERRUPTED) from None
    except BrokenPipeError:
        sys.stderr.close()
        raise typer.Exit(0) from None
    if not found:
        raise fail(f"no record decoded from the raw reads in {path}", 1)


def _nothing_decoded(kept: bytes, codes: set[int], little_endian: bool) -> str:
    """Why nothing decoded, with the option to change when the other byte order works:
    its records must make up most of the input, not be a chance match in garbage."""
    if not kept:
        return "no record decoded: the input is empty"
    found = other_byte_order(kept, codes, little_endian)
    if found:
        fix = "--little-endian" if not little_endian else "without --little-endian"
        return (f"no record decoded, but {found} did with floats "
                f"{'little' if not little_endian else 'big'}-endian: try {fix}")
    return ("no record decoded: not a raw 3DM-GX3 capture, or its records are not among "
            "the expected codes (see --expect)")


def _pieces(values: np.ndarray) -> list[bytes]:
    """Each record's value of one column as JSON text, without its outer brackets.

    One orjson call serialises the whole column (floats widened exactly to float64,
    NaN and infinities as null); splitting at the record boundaries is safe because
    numbers and null contain no brackets. Text (ID strings) is quoted one by one.
    """
    if values.dtype.kind == "S":
        return [orjson.dumps(v.decode("ascii", "replace").rstrip("\x00 "))
                for v in values.tolist()]
    if values.dtype.kind == "f":
        values = values.astype(np.float64)
    depth = values.ndim  # brackets around the column; the record's own are depth - 1
    text = orjson.dumps(values, option=orjson.OPT_SERIALIZE_NUMPY)
    inner = depth - 1
    return text[depth:-depth].split(b"]" * inner + b"," + b"[" * inner)


def _template(batch: Batch, lead: bytes = b"{") -> bytes:
    """One record's line with a %s per field: ``lead`` (the brace, and the unit's name
    from a capture of several), command, then the fields in wire order."""
    parts = [f'{lead.decode().replace("%", "%%")}"command":{batch.code}']
    for name, col in batch.columns.items():
        inner = col.ndim - 1
        parts.append(f',"{name}":{"[" * inner}%s{"]" * inner}')
    return ("".join(parts) + "}\n").encode()


def _lines(batches: list[Batch], lead: bytes = b"{") -> bytes:
    """JSON lines, one per record, as `json.dumps` of the record would give them."""
    out = []
    for batch in batches:
        template = _template(batch, lead)
        if batch.columns:
            out += [template % row for row in zip(*map(_pieces, batch.columns.values()),
                                                  strict=True)]
        else:
            out.append(template * len(batch))
    return b"".join(out)
