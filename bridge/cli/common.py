"""What every `gx3` command shares: the Typer app, the stderr console, one-line errors and
the safe writing of outputs."""

from __future__ import annotations

import inspect
import io
import logging
import os
import signal
import sys
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import orjson
import typer
from rich.console import Console
from rich.markup import escape
from rich.text import Text
from typer.core import TyperGroup, TyperOption

from bridge import __version__
from bridge.exceptions import Gx3Error
from bridge.protocol.table import REPLIES

REFUSED = 2  #: the exit status of a command refused before its work began (options, inputs)
FAILED = 1  #: the exit status of a command whose work failed once begun
#: The exit status of a command stopped by Ctrl-C (or SIGTERM) before its work was done.
#: A service (bridge, record, view, router, sim) runs until it is stopped: stopping it is
#: how it ends, exit 0.
INTERRUPTED = 130


def _paragraphs_wrapped(help_text: str | None) -> str | None:
    """A docstring's paragraphs after its first, each on one line: Typer keeps their line
    breaks (the first's it joins itself), so on an 80-column terminal each source line
    would wrap again half-way. The terminal wraps them instead."""
    if not help_text:
        return help_text
    first, *rest = inspect.cleandoc(help_text).split("\n\n")
    return "\n\n".join([first, *(p.replace("\n", " ") for p in rest)])


def _flags_untyped(command: Any, ctx: Any) -> None:
    """Typer labels an on/off flag ``<bool>`` in help, as if it took a value: show none."""
    for param in [*command.params, command.get_help_option(ctx)]:
        if isinstance(param, TyperOption) and param.is_flag and param.metavar is None:
            param.metavar = ""


class _Commands(TyperGroup):
    """The `gx3` group: help laid out for a terminal, and every ``Gx3Error`` a command
    raises (whatever one raises on purpose) said in one line, exit 2 (``REFUSED``).

    A command whose work had begun when it failed says so itself, inside ``failing``."""

    def __init__(self, **attrs: Any) -> None:
        super().__init__(**attrs)
        for command in [self, *self.commands.values()]:
            command.help = _paragraphs_wrapped(command.help)

    def get_command(self, ctx: Any, cmd_name: str) -> Any:
        command = super().get_command(ctx, cmd_name)
        if command is not None:
            _flags_untyped(command, ctx)
        return command

    def format_help(self, ctx: Any, formatter: Any) -> None:
        _flags_untyped(self, ctx)
        super().format_help(ctx, formatter)

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except Gx3Error as exc:
            raise fail(str(exc)) from None
        except KeyboardInterrupt:
            raise fail("interrupted", INTERRUPTED) from None


app = typer.Typer(
    cls=_Commands,
    name="gx3",
    help="MicroStrain 3DM-GX3 inertial sensors on Zenoh, in MCAP archives and in the "
         "Rerun viewer: bridge each unit, record the fleet, view it live, operate units, "
         "export archives; emulate units to try it all without hardware.",
    epilog="Exit status: 0 done (a service, also when stopped by Ctrl-C or SIGTERM); 2 "
           "refused before any work (options, inputs, outputs); 1 failed at its job; 130 "
           "interrupted.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True, highlight=False, soft_wrap=True)


def fail(message: str, code: int = REFUSED) -> typer.Exit:
    """Print a one-line error for a person and return the exit to raise."""
    err.print(f"[bold red]error:[/] {escape(message)}")
    return typer.Exit(code)


@contextmanager
def failing(*errors: type[Exception], unless: tuple[type[Exception], ...] = (),
            temp: Path | None = None, path: Path | None = None) -> Iterator[None]:
    """Inside, the command's work has begun: these errors end it with exit 1 (``FAILED``),
    where the same errors before it began are a refusal, exit 2 (a disk that fills while
    an archive is written, against an archive refused at the start). Errors of
    ``unless`` stay refusals; a message that names ``temp`` names ``path`` instead (a
    batch output's temporary file)."""
    try:
        yield
    except unless:
        raise
    except errors as exc:
        message = str(exc)
        if temp is not None and path is not None:
            message = message.replace(str(temp), str(path))
        raise fail(message, FAILED) from None


StartOpt = Annotated[str | None, typer.Option(
    metavar="TIME",
    help="First instant: ISO time (2026-11-22T02:50:00Z; no zone = UTC) or seconds "
         "from the first sample.")]
EndOpt = Annotated[str | None, typer.Option(
    metavar="TIME", help="End instant (exclusive), as --start.")]
MetricsOpt = Annotated[str | None, typer.Option(
    "--metrics", metavar="ADDR:PORT",
    help="Serve health to Prometheus here (/metrics): 127.0.0.1:9464 for a Prometheus on "
         "this machine, the fleet network's address for one elsewhere (whoever reaches it "
         "can read the health); :9464 listens on every interface. A bridge serves its "
         "unit's counters, rate, state, clock, host sync and latency; the recorder what "
         "it archived of each unit (docs: monitoring).")]
ForceOpt = Annotated[bool, typer.Option(
    "--force", help="Replace an output file that exists (never an input, nor a file "
                    "another process is writing).")]


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


@contextmanager
def written(path: Path, inputs: Iterable[Path] = (), force: bool = False, *,
            suffixes: Sequence[str]) -> Iterator[Path]:
    """The temporary file a batch command writes ``path`` through (bridge/archive/outputs.py
    ``named_format`` and ``staged``): a refused output (an extension that is none of
    ``suffixes`` too) is a one-line error (exit 2); Ctrl-C or SIGTERM exit 130, and like
    any failure leave nothing under ``path``."""
    from bridge.archive.outputs import named_format, staged

    named_format(path, *suffixes)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with staged(path, inputs, force) as temp:
            yield temp
    except KeyboardInterrupt:
        raise fail(f"interrupted; {path} was not written", INTERRUPTED) from None
    finally:
        signal.signal(signal.SIGTERM, previous)


def refused(path: Path, inputs: Iterable[Path] = (), force: bool = False, *,
            suffixes: Sequence[str]) -> None:
    """bridge/archive/outputs.py ``named_format`` and ``refuse`` for a live output, or one
    checked before its work begins (OutputRefused: exit 2)."""
    from bridge.archive.outputs import named_format, refuse

    named_format(path, *suffixes)
    refuse(path, inputs, force)


def duration_text(seconds: float) -> str:
    """Seconds as a person reads a recording's length: 42 s, 12:05, 3:25:10."""
    whole = int(seconds)
    if whole < 60:
        return f"{whole} s"
    hours, rest = divmod(whole, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


def parse_code(text: str | None) -> int:
    """A command byte as people write it: 0xC8, 200 or 0o310; none is 0."""
    if text is None:
        return 0
    try:
        return int(text, 0)
    except ValueError:
        raise typer.BadParameter(f"{text!r} is not a number such as 0xC8") from None


def reply_code(option: str, text: str) -> int:
    """A reply code given to ``option``, or a one-line error naming the option."""
    try:
        code = int(text, 0)
    except ValueError:
        raise fail(f"{option}: {text!r} is not a number such as 0xC8") from None
    if code not in REPLIES:
        raise fail(f"{option}: no reply starts with 0x{code:02X}; replies start with "
                   + " ".join(f"0x{c:02X}" for c in sorted(REPLIES)))
    return code


class LogFormat(StrEnum):
    text = "text"
    json = "json"


class LogLevel(StrEnum):
    debug = "debug"
    info = "info"
    warning = "warning"
    error = "error"


LogLevelOpt = Annotated[LogLevel, typer.Option(
    "--log-level", case_sensitive=False, metavar="LEVEL",
    help="The least severe log lines shown: debug, info, warning or error (a unit's "
         "bring-up is info, a gap or reset a warning, a disconnect an error). Rerun's own "
         "warnings show only at debug (or as RUST_LOG says, where it is set).")]
LogFormatOpt = Annotated[LogFormat, typer.Option(
    "--log-format", case_sensitive=False, metavar="FORMAT",
    help="text: lines for a person; json: every line on stderr one JSON object (time, "
         "level, logger, message and the record's fields such as event, count, time_ns), "
         "for journald and log shippers.")]

# what every LogRecord carries; anything else came in ``extra`` and is a field of its own
_RECORD_ATTRS = {*vars(logging.LogRecord("", 0, "", 0, "", None, None)), "message", "asctime"}
_LEVELS = {"error:": logging.ERROR, "warning:": logging.WARNING}


class _JsonLines(logging.Formatter):
    """One JSON object per record, as journald and log shippers take them."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(
                timespec="microseconds").replace("+00:00", "Z"),
            "level": record.levelname.lower(), "logger": record.name,
            "message": record.getMessage()}
        line.update((k, v) for k, v in vars(record).items() if k not in _RECORD_ATTRS)
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        return orjson.dumps(line, default=str).decode()


class _ForPeople(logging.Handler):
    """Records on the terminal as people read them: an event's time first and its kind
    in bold, any other warning or error labelled like the commands' own lines."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            time_ns = getattr(record, "time_ns", None)
            stamp = ("" if not isinstance(time_ns, int) else
                     f"[dim]{time.strftime('%H:%M:%S', time.localtime(time_ns / 1e9))}[/] ")
            text = escape(record.getMessage())
            event = getattr(record, "event", None)
            if isinstance(event, str) and text.startswith(event):  # its kind says enough
                label, text = "", f"[bold]{event}[/]{text[len(event):]}"
            else:
                label = ("[bold red]error:[/] " if record.levelno >= logging.ERROR else
                         "[yellow]warning:[/] " if record.levelno >= logging.WARNING else "")
            err.print(f"{stamp}{label}{text}")
        except Exception:
            self.handleError(record)


class _ConsoleLines(io.StringIO):
    """The commands' own stderr lines (``err``) as log records, for ``--log-format json``:
    a shipper then meets nothing but JSON."""

    def __init__(self) -> None:
        super().__init__()
        self._pending = ""
        self._log = logging.getLogger("gx3")

    def write(self, text: str) -> int:
        *lines, self._pending = (self._pending + text).split("\n")
        for line in lines:
            plain = Text.from_ansi(line).plain.strip()
            if plain:
                label = next((k for k in _LEVELS if plain.startswith(k)), None)
                if label is None:
                    self._log.info(plain)
                else:
                    self._log.log(_LEVELS[label], plain.removeprefix(label).lstrip())
        return len(text)


_installed: list[logging.Handler] = []  # what log_to added, replaced by its next call


#: Whether the user set RUST_LOG, the filter of Rerun's own (Rust) log lines: theirs wins.
_RUST_LOG_GIVEN = "RUST_LOG" in os.environ


def log_to(level: LogLevel = LogLevel.info, fmt: LogFormat = LogFormat.text) -> None:
    """Send the library's log records (and, in JSON, the command's own lines) to stderr.

    Rerun's own log lines (a file sink's notes, in raw terminal colours) are a third
    party's: below error they show only at debug. Rerun reads RUST_LOG when it is first
    imported, which every command does after this.
    """
    if not _RUST_LOG_GIVEN:
        os.environ["RUST_LOG"] = "warn" if level is LogLevel.debug else "error"
    root = logging.getLogger()
    while _installed:
        root.removeHandler(_installed.pop())
    handler: logging.Handler
    if fmt is LogFormat.json:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_JsonLines())
        err.file = _ConsoleLines()
    else:
        handler = _ForPeople()
        err.file = None  # type: ignore[assignment]  # rich's default: sys.stderr as it is now
    _installed.append(handler)
    root.addHandler(handler)
    root.setLevel(level.value.upper())


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"gx3 {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    show_version: Annotated[bool, typer.Option(
        "--version", callback=_show_version, is_eager=True,
        help="Print the version and exit.")] = False,
) -> None:
    """Tools for MicroStrain 3DM-GX3 inertial sensors."""
    log_to()
