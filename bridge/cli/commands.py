"""`gx3 commands`: the command table, for people and for the generated files."""

from __future__ import annotations

import json
import shutil
import sys
from typing import Annotated

import typer

from bridge.cli.common import app
from bridge.protocol.docs import command_list_text, command_table_markdown, reply_schemas


@app.command()
def commands(
    markdown: Annotated[bool, typer.Option(
        "--markdown", help="Print the table as Markdown (what docs/commands.md holds).")] = False,
    as_json: Annotated[bool, typer.Option(
        "--json", help="Print every reply's wire layout as JSON (what schemas/replies.json "
        "holds).")] = False,
) -> None:
    """List every 3DM-GX3 command with its bytes, parameters and reply layout."""
    if as_json:
        sys.stdout.write(json.dumps(reply_schemas(), indent=1) + "\n")
    elif markdown:
        sys.stdout.write(command_table_markdown())
    else:
        width = max(40, min(shutil.get_terminal_size().columns, 100))
        sys.stdout.write(command_list_text(width))
