"""`gx3 router`: a Zenoh router from the pip package, for fleets across machines."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import Annotated

import typer

from bridge.cli.common import LogFormat, LogFormatOpt, LogLevel, LogLevelOpt, app, err, log_to

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"


@app.command("router")
def router(
    listen: Annotated[list[str] | None, typer.Option(
        "--listen", metavar="ENDPOINT",
        help=f"Endpoint to listen on (repeatable; default {DEFAULT_LISTEN}, or the "
             "config file's).")] = None,
    zenoh_config: Annotated[Path | None, typer.Option(
        "--zenoh-config", metavar="FILE",
        help="Zenoh JSON5 configuration (TLS, access control, endpoints); its mode is set "
             "to router. configs/fleet/router.json5 is an example.")] = None,
    connect: Annotated[list[str] | None, typer.Option(
        "--connect", metavar="ENDPOINT",
        help="Another router to join, e.g. at a second site (repeatable).")] = None,
    duration: Annotated[float | None, typer.Option(
        min=0.0, help="Stop after this many seconds (default: until Ctrl-C).")] = None,
    log_level: LogLevelOpt = LogLevel.info,
    log_format: LogFormatOpt = LogFormat.text,
) -> None:
    """Run a Zenoh router, so bridges and recorders on several machines find each other.

    Bridges, recorders and apps then connect to it (--connect tcp/ROUTER:7447, or the
    client configuration in configs/fleet/); no separately installed zenohd is needed.
    Multicast scouting is off: clients name the router.
    """
    log_to(log_level, log_format)
    from bridge.bus.session import open_session

    endpoints = listen or ([] if zenoh_config else [DEFAULT_LISTEN])
    session = open_session(zenoh_config, connect=connect or [], listen=endpoints,
                           mode="router", multicast_scouting=False)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        shown = endpoints or ["the endpoints of " + str(zenoh_config)]
        err.print(f"router {session.zid()} listening on {', '.join(shown)}", highlight=False)
        print("READY", flush=True)
        stop.wait(duration)
    finally:
        session.close()
