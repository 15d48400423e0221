"""What the processes one machine runs together need (demo, tests, benchmarks): free
loopback ports, and a way to stop them that lets each close its files and sessions.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import time
from collections.abc import Iterable
from typing import Any


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now: the OS picks it."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def interrupt(procs: Iterable[subprocess.Popen[Any]], timeout: float = 20.0) -> None:
    """Ctrl-C each child that still runs, then wait for all; kill those that have not
    stopped within ``timeout`` seconds of the Ctrl-C (a hung child must not hang its
    parent).
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
