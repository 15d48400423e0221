"""Zenoh sessions from a JSON5 file and command-line flags, with one-line errors.

The file carries whatever the user's network needs (TLS, ACLs, routers, scouting);
``--connect``/``--listen``/``--mode`` override it for the common cases. Zenoh's
own errors name Rust source files and dump parser state: ``condense`` keeps the
part a user can act on. When a client cannot connect, Zenoh does not say why;
``bridge.bus.linkcheck`` finds out (router down, TLS trust, certificate, protocol).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from bridge.bus.linkcheck import why_not
from bridge.exceptions import SessionError

MODES = ("peer", "client", "router")


def condense(exc: BaseException) -> str:
    """The actionable part of a Zenoh error, on one line.

    Args:
        exc: Zenoh's error.

    Returns:
        Its message without Rust source locations or parser state, at most 400
        characters.
    """
    text = re.sub(r"\s*at /\S+?\.rs:\d+\.?", "", str(exc))
    msg = re.search(r'msg: "((?:[^"\\]|\\.)*)"', text)
    where = re.search(r"line: (\d+), column: (\d+)", text)
    pest = re.search(r"-->\s*(\d+):(\d+).*?=\s*(.*)", text, re.S)
    if msg:
        text = msg.group(1).replace('\\"', '"')
        if where and "line" not in text:
            text += f" (line {where.group(1)}, column {where.group(2)})"
    elif pest:
        text = f"{pest.group(3)} (line {pest.group(1)}, column {pest.group(2)})"
    text = " ".join(text.split()).rstrip(".")
    return text if len(text) <= 400 else text[:397] + "..."


@dataclass(frozen=True)
class ZenohOptions:
    """Where a session's configuration comes from: a file, then flags over it.

    ``config_file`` is a JSON5 Zenoh configuration (None: Zenoh's defaults); ``connect``,
    ``listen``, ``mode`` and ``multicast_scouting`` override it, as ``--connect``,
    ``--listen`` and ``--mode`` do.
    """

    config_file: str | Path | None = None
    connect: Sequence[str] = field(default=())
    listen: Sequence[str] = field(default=())
    mode: str | None = None
    multicast_scouting: bool | None = None

    def config(self) -> zenoh.Config:
        """The zenoh.Config these options describe.

        Returns:
            The configuration.

        Raises:
            SessionError: The file is missing or invalid, or a flag's value is; the
                message says what is wrong.
        """
        if self.config_file is not None:
            path = Path(self.config_file)
            if not path.is_file():
                raise SessionError(f"zenoh config {path}: no such file")
            try:
                config = zenoh.Config.from_file(str(path))
            except zenoh.ZError as exc:
                raise SessionError(f"zenoh config {path}: {condense(exc)}") from None
        else:
            config = zenoh.Config()
        if self.mode is not None:
            if self.mode not in MODES:
                raise SessionError(f"--mode {self.mode!r}: use one of {', '.join(MODES)}")
            config.insert_json5("mode", json.dumps(self.mode))
        for flag, key, endpoints in (("--connect", "connect/endpoints", self.connect),
                                     ("--listen", "listen/endpoints", self.listen)):
            if endpoints:
                try:
                    config.insert_json5(key, json.dumps(list(endpoints)))
                except zenoh.ZError as exc:
                    raise SessionError(f"{flag} {' '.join(endpoints)}: {condense(exc)} "
                                       "(e.g. tcp/192.168.1.10:7447)") from None
        if self.multicast_scouting is not None:
            config.insert_json5("scouting/multicast/enabled",
                                json.dumps(self.multicast_scouting))
        return config

    def open(self) -> zenoh.Session:
        """Open a session with these options.

        Returns:
            The session; the caller closes it.

        Raises:
            SessionError: It could not be opened; the message names what failed (the
                configuration, an endpoint, the router, TLS).
        """
        config = self.config()
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            if "Unable to connect" in str(exc):
                raise SessionError(f"zenoh session: {_unreachable(config)}") from None
            raise SessionError(f"zenoh session: {condense(exc)}") from None


def _unreachable(config: zenoh.Config) -> str:
    """Why none of ``config``'s connect endpoints opened, endpoint by endpoint."""
    endpoints = json.loads(config.get_json("connect/endpoints"))
    if isinstance(endpoints, dict):  # endpoints per mode
        endpoints = endpoints.get(json.loads(config.get_json("mode")) or "peer") or []
    tls = json.loads(config.get_json("transport/link/tls"))
    reasons = [why_not(str(e), tls) for e in endpoints]
    said = reasons[0] if len(reasons) == 1 else \
        "; ".join(f"{e}: {r}" for e, r in zip(endpoints, reasons, strict=True))
    return f"Unable to connect to any of [{', '.join(map(str, endpoints))}]: {said}"


def open_session(config_file: str | Path | None = None, *, connect: Sequence[str] = (),
                 listen: Sequence[str] = (), mode: str | None = None,
                 multicast_scouting: bool | None = None) -> zenoh.Session:
    """Open a session from ``--zenoh-config FILE`` and the ``--connect/--listen/--mode`` flags.

    Args:
        config_file: A JSON5 Zenoh configuration; None: Zenoh's defaults.
        connect: Endpoints to connect to, over the file's.
        listen: Endpoints to listen on, over the file's.
        mode: "peer", "client" or "router", over the file's.
        multicast_scouting: Turn multicast scouting on or off, over the file's.

    Returns:
        The session; the caller closes it.

    Raises:
        SessionError: It could not be opened; the message names what failed.
    """
    return ZenohOptions(config_file, connect, listen, mode, multicast_scouting).open()
