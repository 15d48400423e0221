"""`gx3` commands run in this process with Typer's runner: what they say and leave, in
milliseconds, where a test is about messages and files rather than a process."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner, Result

from bridge.cli import app


def gx3_here(*args: str | Path) -> Result:
    """``gx3 ARGS`` in this process, 300 columns wide: its exit code, stdout and stderr."""
    return CliRunner().invoke(app, [str(a) for a in args], env={"COLUMNS": "300"})
