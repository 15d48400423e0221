"""Operator actions on running bridges: the client side of the command queryable.

``gx3 configure --unit NAME`` (or a key expression for the fleet) sends one JSON
request to ``<prefix>/<unit>/command`` and prints each bridge's answer. Reading
identity needs no permission: ``info`` asks the info queryable instead.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh
from google.protobuf.json_format import MessageToDict

from bridge.bus.gx3_pb2 import Info
from bridge.bus.keys import PREFIX, unit_of
from bridge.bus.session import SessionError, ZenohOptions

#: How long to wait for answers; capture-bias runs for its sampling time first.
TIMEOUT_S = 10.0


class RemoteError(RuntimeError):
    """No bridge could be asked; the message says why."""


def ask_units(prefix: str, unit: str, action: str, params: dict[str, Any], *,
              zenoh_config: str | Path | None = None, connect: Sequence[str] = (),
              timeout: float = TIMEOUT_S) -> list[tuple[str, bool, dict[str, Any]]]:
    """(unit, ok, result or {"error": text}) for every bridge that answered."""
    if action == "capture_bias":
        timeout += int(params.get("sampling_ms", 10_000)) / 1000
    try:
        session = ZenohOptions(zenoh_config, connect).open()
    except SessionError as exc:
        raise RemoteError(str(exc)) from None
    try:
        if action == "info":
            replies = session.get(f"{prefix}/{unit}/info", timeout=timeout)
        else:
            request = json.dumps({"action": action, "params": params, "confirm": True})
            replies = session.get(f"{prefix}/{unit}/command", payload=request, timeout=timeout)
        out = [_answer(prefix, reply, action) for reply in replies]
    finally:
        session.close()
    if not out:
        raise RemoteError(f"no bridge answered for {prefix}/{unit}: is it running, and can "
                          "this machine reach it (--connect, --zenoh-config)?")
    return sorted(out)


def _answer(prefix: str, reply: zenoh.Reply, action: str) -> tuple[str, bool, dict[str, Any]]:
    if reply.ok is None:
        text = reply.err.payload.to_string() if reply.err is not None else "no answer"
        unit, _, message = text.partition(": ")
        return (unit, False, {"error": message or text})
    sample = reply.ok
    unit = unit_of(str(sample.key_expr), prefix or PREFIX)
    payload = sample.payload.to_bytes()
    if action == "info":
        info = Info()
        info.ParseFromString(payload)
        return (unit, True, MessageToDict(info, preserving_proto_field_name=True))
    return (unit, True, json.loads(payload))
