"""Render the command table as Markdown, so the reference can never drift from the code."""

from __future__ import annotations

import textwrap
from typing import Any

from bridge.protocol.table import (
    COMMANDS,
    DATA_CODES,
    ERROR_REPLY,
    REPLIES,
    Command,
    Field,
    Mode,
    When,
)

SCHEMA_VERSION = 1


def record_text(code: int) -> str:
    """A data record as an operator reads it, from the table: its code and quantities.

    Args:
        code: The record's command byte; 0 for none (a preset that was never set).

    Returns:
        ``0xCC (accel, ang_rate, mag, m)``, ``none`` for 0, the bare code for a byte
        that is not a data record.
    """
    if not code:
        return "none"
    spec = REPLIES.get(code)
    if spec is None or code not in DATA_CODES:
        return f"0x{code:02X}"
    quantities = ", ".join(f.name for f in spec.fields if f.name != "timer" and not f.is_pad)
    return f"0x{code:02X} ({quantities})"


def mode_text(mode: int) -> str:
    """A mode (0xD4) or mode preset (0xD5) as an operator reads it: ``2 (continuous)``.

    Args:
        mode: The mode's value.

    Returns:
        The value and its name, or the value alone where the manual names none.
    """
    try:
        return f"{mode} ({Mode(mode).name.lower().replace('_', ' ')})"
    except ValueError:
        return str(mode)


def _field(f: Field) -> str:
    shape = "×".join(str(s) for s in f.shape)
    kind = f"{shape} × {f.kind}" if f.shape and not f.is_pad else f.kind
    if f.is_pad:
        return f"reserved ({f.count} bytes)"
    rule = ""
    values = f.allowed if f.allowed is not None else f.domain_values
    low, high = (f.lo, f.hi) if f.lo is not None else f.domain or (None, None)
    if values is not None and len(values) <= 8:
        rule = " ∈ {" + ", ".join(str(v) for v in sorted(values)) + "}"
    elif low is not None and high is not None and f.kind != "f32":
        rule = f" ∈ [{low:g}, {high:g}]"
    unit = f" [{f.unit}]" if f.unit else ""
    return f"`{f.name}` {kind}{unit}{rule}"


def _when(*rules: When) -> str:
    """' when function=2 or ...' for the notes; empty for a rule that always holds."""
    shown = []
    for w in rules:
        if w.param is None:
            return ""
        values = sorted(w.values)
        if w.values == DATA_CODES:
            text = f"{w.param} is a data command"
        elif len(values) == 1:
            text = f"{w.param}={values[0]}"
        else:
            text = f"{w.param} in {{{', '.join(str(v) for v in values)}}}"
        if w.before_firmware is not None:
            text += f" on firmware before {_version(w.before_firmware)}"
        shown.append(text)
    return " when " + " or ".join(shown)


def _version(number: int) -> str:
    """0xE9's version number as the manual writes it: 1127 is 1.1.27."""
    return f"{number // 1000}.{number // 100 % 10}.{number % 100}"


_INTRO = (
    "Multi-byte integers, the timer and the checksum are big-endian; floats are "
    "IEEE-754 float32, big-endian unless 0xDB flag bit 4 is set. The checksum is "
    "the 16-bit wrapping sum of all preceding reply bytes. A wrong confirmation "
    f"sequence is answered with the error reply `{ERROR_REPLY.hex(' ')}`."
)


def _notes(c: Command) -> list[str]:
    notes = []
    if c.data:
        notes.append("data record, valid continuous preset")
    if c.persists_when:
        notes.append(f"changes non-volatile state{_when(*c.persists_when)}: "
                     "sent only on explicit request")
    if c.silent_when:
        notes.append(f"no reply{_when(c.silent_when)}")
    if c.ignored_when:
        notes.append(f"{', '.join(c.ignored)} ignored (may be left out){_when(c.ignored_when)}")
    if c.notes:
        notes.append(c.notes)
    return notes


def command_table_markdown() -> str:
    """The whole command set as a Markdown table, as ``gx3 commands --markdown`` prints it.

    Returns:
        A page: title, the byte-order rules, then one row per command (bytes sent,
        confirmation, parameters, reply layout, notes).
    """
    lines = [
        "# 3DM-GX3 command reference",
        "",
        "Generated from `bridge/protocol/table.py` by `gx3 commands --markdown`.",
        *textwrap.wrap(_INTRO, 80),
        "",
        "| code | name | sends | confirmation | parameters | reply | reply fields | notes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in COMMANDS.values():
        params = "<br>".join(_field(f) for f in c.params) or "–"
        if c.reply is None:
            reply, fields = "none", "–"
        else:
            reply = f"{c.reply_length} B"
            fields = "<br>".join(_field(f) for f in c.reply) or "–"
        sends = f"{c.length} B" if c.documented else "?"
        confirm = c.confirm.hex(" ") or "–"
        lines.append(f"| 0x{c.code:02X} | {c.name} | {sends} | {confirm} | {params} | {reply} "
                     f"| {fields} | {'; '.join(_notes(c))} |")
    return "\n".join(lines) + "\n"


def _bytes(n: int | None) -> str:
    return "1 byte" if n == 1 else f"{n} bytes"


def command_list_text(width: int = 80) -> str:
    """The same reference as a list for a terminal, as ``gx3 commands`` prints it.

    Args:
        width: The terminal's columns.

    Returns:
        The text, wrapped to ``width``.
    """
    indent = " " * 6

    def wrap(text: str) -> list[str]:
        return textwrap.wrap(text.replace("`", ""), width, initial_indent=indent,
                             subsequent_indent=indent + "  ", break_on_hyphens=False)

    lines = [*textwrap.wrap(_INTRO.replace("`", ""), width), ""]
    for c in COMMANDS.values():
        lines += textwrap.wrap(f"0x{c.code:02X}  {c.name}: {c.title}", width,
                               subsequent_indent=indent)
        sends = _bytes(c.length) if c.documented else "layout undocumented"
        confirm = f", confirmation {c.confirm.hex(' ')}" if c.confirm else ""
        lines += wrap(f"sends {sends}{confirm}")
        for f in c.params:
            lines += wrap(f"param {_field(f)}")
        if c.reply is None:
            lines += wrap("no reply")
        else:
            lines += wrap(f"reply {_bytes(c.reply_length)}" + (":" if c.reply else ""))
            for f in c.reply:
                lines += wrap(f"  {_field(f)}")
        for note in _notes(c):
            lines += wrap(note)
        lines.append("")
    return "\n".join(lines)


def reply_schemas() -> dict[str, Any]:
    """Every reply's wire layout, language-neutral, for decoders written elsewhere.

    Returns:
        JSON-able: the byte order, checksum and plausibility rules, then per reply its
        code, name, length and fields (name, offset, type, shape, range or values, unit,
        doc), as the package ships it in ``replies.json``.
    """
    replies = []
    for spec in REPLIES.values():
        offset, fields = 1, []
        for f in spec.fields:
            if not f.is_pad:
                entry: dict[str, Any] = {"name": f.name, "offset": offset, "type": f.kind,
                                         "shape": list(f.shape)}
                if f.domain is not None:
                    entry["range"] = list(f.domain)
                if f.domain_values is not None:
                    entry["values"] = sorted(f.domain_values)
                if f.unit:
                    entry["unit"] = f.unit
                if f.doc:
                    entry["doc"] = f.doc
                fields.append(entry)
            offset += f.size
        replies.append({"code": spec.code, "name": spec.name, "length": spec.length,
                        "fields": fields})
    return {
        "schema": "gx3-bridge/replies",
        "version": SCHEMA_VERSION,
        "byte_order": "big-endian; f32 little-endian when 0xDB flag bit 4 is set",
        "checksum": "u16 big-endian in the last two bytes: sum of all preceding bytes mod 65536",
        "types": {"u8": 1, "u16": 2, "u32": 4, "f32": 4, "ascii": 16},
        "plausible": "what a unit can send: a field's values lie in its range (f32: or are "
                     "NaN or infinite) or among its values; a candidate with any other value "
                     "is garbage that matched the checksum",
        "replies": replies,
    }
