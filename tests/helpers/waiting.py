"""Waiting on what other processes and threads do: a condition, a generous deadline."""

from __future__ import annotations

import time
from collections.abc import Callable

from bridge.fleet.loopback import free_port

__all__ = ["free_port", "wait_for"]


def wait_for(condition: Callable[[], bool], timeout: float = 60.0,
             what: str = "the condition") -> None:
    """Poll ``condition`` until it holds; fail after ``timeout`` seconds (a busy CI
    machine is slow, so deadlines are wide and nothing here is a timing window)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)
