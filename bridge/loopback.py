"""What the processes one machine runs together need (demo, tests, benchmarks): free
loopback ports, and a way to stop them that lets each close its files and sessions."""

from __future__ import annotations

import signal
import socket
import subprocess
from collections.abc import Iterable
from typing import Any


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now: the OS picks it."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def interrupt(procs: Iterable[subprocess.Popen[Any]], timeout: float = 20.0) -> None:
    """Ctrl-C each child that still runs, then wait for all; kill one that has not
    stopped within ``timeout`` seconds (a hung child must not hang its parent)."""
    procs = list(procs)
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in procs:
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
