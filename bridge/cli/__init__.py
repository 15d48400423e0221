"""The `gx3` command line: one Typer app, one module per group of commands."""

from bridge.cli import bridge, commands, decode, operate, sim
from bridge.cli.common import app

__all__ = ["app", "bridge", "commands", "decode", "operate", "sim"]
