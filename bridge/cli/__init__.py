"""The `gx3` command line: one Typer app, one module per group of commands."""

from bridge.cli import archive, bridge, commands, decode, operate, record, sim
from bridge.cli.common import app

__all__ = ["app", "archive", "bridge", "commands", "decode", "operate", "record", "sim"]
