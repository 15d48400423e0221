"""The `gx3` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, BinaryIO

import typer
from rich.console import Console

from bridge.protocol.codec import json_safe
from bridge.protocol.docs import command_table_markdown
from bridge.protocol.framer import Framer
from bridge.protocol.table import DATA_CODES, REPLIES

app = typer.Typer(
    name="gx3",
    help="Bridge MicroStrain 3DM-GX3 inertial sensors onto Zenoh, MCAP and Rerun.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True, highlight=False)

_READ_SIZE = 1 << 20


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error for a person and return the exit to raise."""
    err.print(f"[bold red]error:[/] {message}")
    return typer.Exit(code)


def _reply_code(text: str) -> int:
    try:
        code = int(text, 0)
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a number such as 0xC8") from None
    if code not in REPLIES:
        raise typer.BadParameter(f"no reply starts with 0x{code:02X}")
    return code


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
    file: Annotated[str, typer.Argument(help="File of raw bytes as read off the line; - for stdin.")],
    little_endian: Annotated[bool, typer.Option(
        "--little-endian", help="Floats were sent little-endian (0xDB flag bit 4 set).")] = False,
    expect: Annotated[list[str] | None, typer.Option(
        "--expect", "-e", metavar="CODE",
        help="Reply code to look for, e.g. 0xC8 or 0xD4 (repeatable). "
             "Default: every data record.")] = None,
) -> None:
    """Decode a raw capture: one JSON object per record on stdout, a summary on stderr.

    Each object has "command" (integer), "timer" where the record has one, and
    each quantity under its DESIGN.md name (vectors and matrices as nested
    lists, matrices row-major). NaN is written as null. Corrupt bytes are
    skipped and counted; every intact record after them is still decoded.
    """
    codes = [_reply_code(c) for c in expect] if expect else sorted(DATA_CODES)
    framer = Framer(codes, little_endian=little_endian)
    out = sys.stdout
    stream = _open_input(file)
    try:
        with stream:
            while chunk := stream.read(_READ_SIZE):
                _write(framer.feed(chunk), out)
            _write(framer.flush(), out)
        out.flush()
    except BrokenPipeError:
        sys.stderr.close()
        raise typer.Exit(0) from None
    err.print(framer.stats.summary())


def _write(batches: list, out) -> None:
    for batch in batches:
        for record in batch.records():
            out.write(json.dumps({k: json_safe(v) for k, v in record.items()}) + "\n")


@app.command()
def commands(
    markdown: Annotated[bool, typer.Option(
        "--markdown", help="Print the table as Markdown (what docs/commands.md holds).")] = False,
) -> None:
    """List every 3DM-GX3 command with its bytes, parameters and reply layout."""
    text = command_table_markdown()
    if markdown:
        sys.stdout.write(text)
    else:
        from rich.markdown import Markdown

        Console().print(Markdown(text))


def main() -> None:
    app()
