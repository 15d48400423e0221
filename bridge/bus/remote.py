"""Operator actions on running bridges: the client side of the command queryable.

``gx3 configure --unit NAME`` (or a key expression for the fleet) sends one JSON
request to ``<prefix>/<unit>/command`` and prints each bridge's answer. Reading
identity needs no permission: ``info`` asks the info queryable instead.

A fresh session knows nothing of the fleet yet, and a query goes only to the
queryables its session has discovered: sent at once, it can find none (a bridge
reached through another peer is discovered a moment later). So the target's
liveliness token is awaited first: a bridge declares its queryables before its
token, and one session's declarations arrive in order. Knowing the bridge is alive
also tells "not running" apart from "alive but no answer", which is what a query
that the router's access control drops looks like (it drops it without a word).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import zenoh
from google.protobuf.json_format import MessageToDict

from bridge.bus.gx3_pb2 import Info
from bridge.bus.integrity import intact
from bridge.bus.keys import PREFIX, unit_of
from bridge.bus.session import ZenohOptions
from bridge.exceptions import RemoteError, SessionError

#: How long to wait for answers; capture-bias runs for its sampling time first.
TIMEOUT_S = 10.0
#: How long a fresh session waits to discover the target's liveliness token: discovery
#: takes milliseconds, on a busy machine a second or two.
DISCOVERY_S = 5.0


def ask_units(prefix: str, unit: str, action: str, params: dict[str, Any], *,
              zenoh_config: str | Path | None = None, connect: Sequence[str] = (),
              timeout: float = TIMEOUT_S,
              discovery: float = DISCOVERY_S) -> list[tuple[str, bool, dict[str, Any]]]:
    """Ask running bridges to run an operator action on their units.

    Args:
        prefix: The keys' prefix.
        unit: A unit's name, or a key expression chunk for several (``*``).
        action: An action of ``bridge.device.ACTIONS``; ``info`` asks the info queryable,
            which needs no permission to act.
        params: The action's parameters.
        zenoh_config: A Zenoh configuration file.
        connect: Endpoints to connect to, over the file's.
        timeout: Seconds to wait for answers (capture-bias adds its sampling time).
        discovery: Seconds to wait for the target's liveliness token.

    Returns:
        (unit, ok, result or {"error": text}) for every bridge that answered, and an
        error for every bridge seen alive that did not, sorted by unit.

    Raises:
        RemoteError: No session could be opened, no bridge is running for the key, or
            none answered; the message says what to check.
    """
    if action == "capture_bias":
        timeout += int(params.get("sampling_ms", 10_000)) / 1000
    key = f"{prefix}/{unit}/{'info' if action == 'info' else 'command'}"
    try:
        session = ZenohOptions(zenoh_config, connect).open()
    except SessionError as exc:
        raise RemoteError(str(exc)) from None
    try:
        deadline = time.monotonic() + discovery
        alive = _Alive(session, f"{prefix}/{unit}/alive", prefix)
        if not alive.wait(deadline):
            raise RemoteError(
                f"no bridge is running for {prefix}/{unit} (no liveliness token "
                f"{prefix}/{unit}/alive within {discovery:g} s): start it, or check that "
                "this machine reaches the fleet (--connect, --zenoh-config)")
        querier = session.declare_querier(key, target=zenoh.QueryTarget.ALL, timeout=timeout)
        if action == "info":
            replies = querier.get()
        else:
            replies = querier.get(payload=json.dumps(
                {"action": action, "params": params, "confirm": True}))
        out = [_answer(prefix, reply, action) for reply in replies]
        silent = sorted(set(alive.units()) - {name for name, _, _ in out})
    finally:
        session.close()  # undeclares the watch and the querier
    if not out:
        what = "operator commands need an operator's certificate" if key.endswith("command") \
            else "info needs a certificate from the fleet's CA"
        raise RemoteError(
            f"{', '.join(silent)} {'is' if len(silent) == 1 else 'are'} alive but did not "
            f"answer on {key} within {timeout:g} s: the router's access control may refuse "
            f"this client the query ({what}; see configs/tls/router-acl.json5), or the "
            "bridge is stuck")
    return sorted(out + [(name, False, {"error": f"alive but did not answer on {key} within "
                                                 f"{timeout:g} s"}) for name in silent])


class _Alive:
    """The units whose liveliness token matches ``token``, as the session learns them."""

    def __init__(self, session: zenoh.Session, token: str, prefix: str) -> None:
        self._prefix = prefix
        self._lock = threading.Lock()
        self._seen: set[str] = set()
        self._found = threading.Event()
        session.liveliness().declare_subscriber(token, self._on_token, history=True)

    def _on_token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            with self._lock:
                self._seen.add(unit_of(str(sample.key_expr), self._prefix))
            self._found.set()

    def wait(self, deadline: float) -> bool:
        """Whether one is alive, waiting for it until ``deadline``."""
        return self._found.wait(max(0.0, deadline - time.monotonic()))

    def units(self) -> list[str]:
        with self._lock:
            return sorted(self._seen)


def _answer(prefix: str, reply: zenoh.Reply, action: str) -> tuple[str, bool, dict[str, Any]]:
    if reply.ok is None:
        text = reply.err.payload.to_string() if reply.err is not None else "no answer"
        unit, _, message = text.partition(": ")
        return (unit, False, {"error": message or text})
    sample = reply.ok
    unit = unit_of(str(sample.key_expr), prefix or PREFIX)
    payload = sample.payload.to_bytes()
    if action == "info":
        attachment = None if sample.attachment is None else sample.attachment.to_bytes()
        if not intact(payload, attachment):
            return (unit, False, {"error": "its Info reply does not match the CRC-32 attached "
                                           "(damaged in transit, or an old bridge): ask again"})
        info = Info()
        info.ParseFromString(payload)
        return (unit, True, MessageToDict(info, preserving_proto_field_name=True))
    return (unit, True, json.loads(payload))
