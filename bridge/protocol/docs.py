"""Render the command table as Markdown, so the reference can never drift from the code."""

from __future__ import annotations

from typing import Any

from bridge.protocol.table import COMMANDS, ERROR_REPLY, REPLIES, Field

SCHEMA_VERSION = 1


def _field(f: Field) -> str:
    shape = "×".join(str(s) for s in f.shape)
    kind = f"{shape} × {f.kind}" if f.shape and not f.is_pad else f.kind
    if f.is_pad:
        return f"reserved ({f.count} bytes)"
    rule = ""
    if f.allowed is not None and len(f.allowed) <= 8:
        rule = " ∈ {" + ", ".join(str(v) for v in sorted(f.allowed)) + "}"
    elif f.lo is not None and f.hi is not None and f.kind != "f32":
        rule = f" ∈ [{f.lo:g}, {f.hi:g}]"
    unit = f" [{f.unit}]" if f.unit else ""
    return f"`{f.name}` {kind}{unit}{rule}"


def command_table_markdown() -> str:
    """The whole command set: bytes sent, confirmation, parameters, reply layout."""
    lines = [
        "# 3DM-GX3 command reference",
        "",
        "Generated from `bridge/protocol/table.py` by `gx3 commands --markdown`.",
        "Multi-byte integers, the timer and the checksum are big-endian; floats are",
        "IEEE-754 float32, big-endian unless 0xDB flag bit 4 is set. The checksum is",
        "the 16-bit wrapping sum of all preceding reply bytes. A wrong confirmation",
        f"sequence is answered with the error reply `{ERROR_REPLY.hex(' ')}`.",
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
        notes = []
        if c.data:
            notes.append("data record, valid continuous preset")
        if c.persists or c.persists_when:
            when = f" when {c.persists_when[0]}={c.persists_when[1]}" if c.persists_when else ""
            notes.append(f"changes non-volatile state{when}: sent only on explicit request")
        if c.silent_when:
            notes.append(f"no reply when {c.silent_when[0]}={c.silent_when[1]}")
        if c.notes:
            notes.append(c.notes)
        sends = f"{c.length} B" if c.documented else "?"
        confirm = c.confirm.hex(" ") or "–"
        lines.append(f"| 0x{c.code:02X} | {c.name} | {sends} | {confirm} | {params} | {reply} "
                     f"| {fields} | {'; '.join(notes)} |")
    return "\n".join(lines) + "\n"


def reply_schemas() -> dict[str, Any]:
    """Every reply's wire layout, language-neutral, for decoders written elsewhere."""
    replies = []
    for spec in REPLIES.values():
        offset, fields = 1, []
        for f in spec.fields:
            if not f.is_pad:
                entry: dict[str, Any] = {"name": f.name, "offset": offset, "type": f.kind,
                                         "shape": list(f.shape)}
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
        "replies": replies,
    }
