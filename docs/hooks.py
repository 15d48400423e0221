"""MkDocs hook: the pages that the code itself writes.

A page holds a marker where generated Markdown goes, so the reference can never drift
from the code it describes:

- ``<!-- gx3: cli -->``: every ``gx3`` command, from the Typer app (``bridge.cli.app``):
  its help text, its usage and each argument and option with its help, as ``--help``
  gives them;
- ``<!-- gx3: command-table -->``: the 3DM-GX3 command table, rendered by
  ``bridge.protocol.docs`` from ``bridge/protocol/table.py`` (what ``gx3 commands
  --markdown`` prints);
- ``<!-- gx3: quantities -->``: every reply field of the command table
  (``bridge.protocol.table.QUANTITIES``) with its shape, unit and meaning;
- ``<!-- gx3: changelog -->``: the repository's ``CHANGELOG.md``, its links to pages
  under ``docs/`` made the site's.

A page without a marker is left as it is. Named in ``mkdocs.yml`` under ``hooks``.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # the checkout's own package, installed or not
    sys.path.insert(0, str(ROOT))

MARKER = re.compile(r"^<!-- gx3: ([a-z-]+) -->$", re.M)

#: Characters Markdown would read as markup in a help text.
_MARKUP = re.compile(r"([\\`*_\[\]|])")


def _text(help_text: str) -> str:
    """A help text as Markdown that shows it literally."""
    text = _MARKUP.sub(r"\\\1", help_text)
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _paragraphs(help_text: str | None) -> list[str]:
    """A docstring's paragraphs, each on one line (the terminal wraps them too)."""
    blocks = re.split(r"\n\s*\n", (help_text or "").strip())
    return [" ".join(line.strip() for line in block.splitlines() if line.strip() != "\b")
            for block in blocks if block.strip()]


def _params_table(command: Any, ctx: Any) -> list[str]:
    """Each argument and option with its help, grouped in the panels ``--help`` shows."""
    panels: dict[str, list[tuple[str, str]]] = {}
    for param in command.get_params(ctx):
        record = param.get_help_record(ctx)
        if record is None or "--help" in param.opts:
            continue
        names, help_text = record
        kind = "Arguments" if param.param_type_name == "argument" else "Options"
        panel = getattr(param, "rich_help_panel", None) or kind
        if param.param_type_name == "argument":
            names = names.upper()
        panels.setdefault(panel, []).append((names, help_text))
    lines: list[str] = []
    for panel, rows in panels.items():
        first = "argument" if rows[0][0].isupper() else "option"
        lines += [f"**{panel}**", "", f"| {first} | what it does |", "|---|---|"]
        lines += [f"| `{names}` | {_text(' '.join(help_text.split()))} |"
                  for names, help_text in rows]
        lines.append("")
    return lines


def cli_reference() -> str:
    """Every ``gx3`` command as Markdown, in the order and panels of ``gx3 --help``."""
    import typer.main

    from bridge.cli import app

    root = typer.main.get_command(app)
    ctx = root.make_context("gx3", [], resilient_parsing=True)
    names = [name for name in root.list_commands(ctx)
             if not root.get_command(ctx, name).hidden]
    panels: dict[str, list[str]] = {}
    for name in names:
        panel = getattr(root.get_command(ctx, name), "rich_help_panel", None) or "Commands"
        panels.setdefault(panel, []).append(name)
    lines = [*(_text(p) for p in _paragraphs(root.help)), "",
             "`gx3 COMMAND --help` shows the same text in a terminal.", ""]
    for panel, commands in panels.items():
        lines += [f"### {panel}", ""]
        for name in commands:
            command = root.get_command(ctx, name)
            sub = command.make_context(name, [], parent=ctx, resilient_parsing=True)
            paragraphs = _paragraphs(command.help)
            usage = " ".join(command.collect_usage_pieces(sub))
            lines += [f"#### gx3 {name}", ""]
            lines += [f"{_text(paragraphs[0])}" if paragraphs else "", ""]
            lines += ["```text", f"gx3 {name} {usage}", "```", ""]
            for paragraph in paragraphs[1:]:
                lines += [_text(paragraph), ""]
            lines += _params_table(command, sub)
    return "\n".join(lines)


def command_table() -> str:
    """The command table, as ``gx3 commands --markdown`` prints it, without its title."""
    from bridge.protocol.docs import command_table_markdown

    text = re.sub(r"\A# .*\n+", "", command_table_markdown())
    # the page says where the table comes from; the file's own note names the command
    return re.sub(r"\AGenerated from .+?\.(?=\s)\s+", "", text, flags=re.S)


def quantities() -> str:
    """Every reply field of the command table: its name, shape, unit and meaning."""
    from bridge.protocol.table import QUANTITIES

    lines = ["| name | element | shape | unit | what it is |", "|---|---|---|---|---|"]
    for name, field in QUANTITIES.items():
        shape = "×".join(str(n) for n in field.shape) or "scalar"
        lines.append(f"| `{name}` | {field.kind} | {shape} | {_text(field.unit or '–')} "
                     f"| {_text(field.doc or '')} |")
    return "\n".join(lines) + "\n"


def changelog() -> str:
    """The repository's CHANGELOG.md, its links into ``docs/`` made the site's.

    In the repository it links a page as ``docs/guides/monitoring.md``, from its root; on
    the site it is a page in ``docs/`` itself, where that link is
    ``guides/monitoring.md``. A relative link to anything outside ``docs/`` has no page
    on the site: it is refused, with what to do.
    """

    def rebased(match: re.Match[str]) -> str:
        target = match.group(1)
        if re.match(r"[a-zA-Z][\w+.-]*:|#", target):  # a URL, or an anchor of its own
            return match.group(0)
        if not target.startswith("docs/"):
            raise ValueError(f"CHANGELOG.md links {target}, which the site has no page for; "
                             "link a page under docs/, or a URL")
        return f"]({target.removeprefix('docs/')})"

    return re.sub(r"\]\(([^)\s]+)\)", rebased, (ROOT / "CHANGELOG.md").read_text(encoding="utf-8"))


GENERATORS = {"cli": cli_reference, "command-table": command_table, "quantities": quantities,
              "changelog": changelog}


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Replace each marker on a page with the Markdown its generator writes."""

    def generated(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in GENERATORS:
            raise ValueError(f"{page.file.src_path}: no generator named {name!r} "
                             f"(known: {', '.join(GENERATORS)})")
        return GENERATORS[name]()

    return MARKER.sub(generated, markdown)
