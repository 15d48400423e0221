"""What every `gx3` command shares: the Typer app, the stderr console, one-line errors and
the safe writing of outputs."""

from __future__ import annotations

import signal
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Annotated, Any

import typer
import typer.rich_utils
from rich.console import Console
from rich.markup import escape
from typer.core import TyperOption

from bridge.protocol.table import REPLIES

_type_of_option = TyperOption.display_type_rich


def _flag_shows_no_type(self: TyperOption, ctx: Any) -> str | None:
    """Typer labels on/off flags ``<bool>`` in help, as if they took a value: show none."""
    return None if self.is_flag else _type_of_option(self, ctx)


TyperOption.display_type_rich = _flag_shows_no_type  # type: ignore[method-assign]


def _wrapped_paragraphs(paragraphs: list[str], markup_mode: Any) -> str:
    """Typer keeps a docstring's line breaks after its first paragraph, so on an
    80-column terminal each source line wraps again half-way: let the terminal wrap."""
    return "\n\n".join(p.replace("\n", " ") for p in paragraphs)


typer.rich_utils._fix_linebreaks = _wrapped_paragraphs

app = typer.Typer(
    name="gx3",
    help="MicroStrain 3DM-GX3 inertial sensors on Zenoh, in MCAP archives and in the "
         "Rerun viewer: bridge each unit, record the fleet, view it live, operate units, "
         "export archives; emulate units to try it all without hardware.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
err = Console(stderr=True, highlight=False, soft_wrap=True)


def fail(message: str, code: int = 2) -> typer.Exit:
    """Print a one-line error for a person and return the exit to raise."""
    err.print(f"[bold red]error:[/] {escape(message)}")
    return typer.Exit(code)


ForceOpt = Annotated[bool, typer.Option(
    "--force", help="Replace an output file that exists (never an input, nor a file "
                    "another process is writing).")]


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


@contextmanager
def written(path: Path, inputs: Iterable[Path] = (), force: bool = False) -> Iterator[Path]:
    """The temporary file a batch command writes ``path`` through (bridge/outputs.py
    ``staged``): a refused output is a one-line error (exit 2); Ctrl-C or SIGTERM exit
    130, and like any failure leave nothing under ``path``."""
    from bridge.outputs import OutputRefused, staged

    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        with staged(path, inputs, force) as temp:
            yield temp
    except OutputRefused as exc:
        raise fail(str(exc)) from None
    except KeyboardInterrupt:
        raise fail(f"interrupted; {path} was not written", 130) from None
    finally:
        signal.signal(signal.SIGTERM, previous)


def refused(path: Path, inputs: Iterable[Path] = (), force: bool = False) -> None:
    """bridge/outputs.py ``refuse`` for a live output, as a one-line error (exit 2)."""
    from bridge.outputs import OutputRefused, refuse

    try:
        refuse(path, inputs, force)
    except OutputRefused as exc:
        raise fail(str(exc)) from None


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


def _package_version() -> str:
    try:
        return version("gx3-bridge")
    except PackageNotFoundError:
        return "unknown"


def _show_version(value: bool) -> None:
    if value:
        typer.echo(f"gx3 {_package_version()}")
        raise typer.Exit()


@app.callback()
def main(
    show_version: Annotated[bool, typer.Option(
        "--version", callback=_show_version, is_eager=True,
        help="Print the version and exit.")] = False,
) -> None:
    """Tools for MicroStrain 3DM-GX3 inertial sensors."""
