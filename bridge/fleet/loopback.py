"""What the processes one machine runs together need: free loopback ports, a clean stop.

The demo, the tests and the benchmarks run processes side by side: they need ports
nothing listens on, Zenoh configurations that find each other on loopback alone, and a
way to stop them that lets each close its files and sessions.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now: the OS picks it.

    Returns:
        The port.
    """
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback_config(path: Path, listen: Iterable[str] = (), connect: Iterable[str] = (),
                    mode: str = "peer", gossip: bool = False) -> Path:
    """Write a Zenoh configuration that meets others only at the endpoints it names.

    Multicast scouting is off, so that sessions on one machine never find another
    machine's (or another test's) on the network.

    Args:
        path: The JSON5 file to write (``--zenoh-config`` takes it).
        listen: Endpoints to listen on (``tcp/127.0.0.1:PORT``).
        connect: Endpoints to connect to.
        mode: ``peer`` or ``client``.
        gossip: Let peers tell each other of further peers.

    Returns:
        ``path``.
    """
    path.write_text(json.dumps({
        "mode": mode, "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": list(connect)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": gossip}},
    }, indent=1) + "\n")
    return path


def interrupt(procs: Iterable[subprocess.Popen[Any]], timeout: float = 20.0) -> None:
    """Ctrl-C each child that still runs, then wait for all.

    Those that have not stopped within the timeout are killed: a hung child must not
    hang its parent.

    Args:
        procs: The children.
        timeout: Seconds from the Ctrl-C to the kill.
    """
    procs = list(procs)
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    for proc in procs:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
