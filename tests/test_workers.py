"""Work shared out among processes (``gx3 replay -j``, ``gx3 allan``): what every worker
sends arrives, a worker's error reaches the caller, and no worker is left behind."""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import psutil
import pytest

from bridge._workers import Workers, share_out
from bridge.exceptions import ReplayError


def _count(share: list[int], send: Callable[[int], None]) -> None:
    for item in share:
        send(item)


def _fail(share: list[int], send: Callable[[int], None]) -> None:
    send(share[0])
    raise ValueError(f"item {share[0]} is odd")


def _die(share: list[int], send: Callable[[int], None]) -> None:
    os._exit(3)


def _sleep(share: list[int], send: Callable[[int], None]) -> None:
    send(os.getpid())
    time.sleep(60)


def test_what_every_worker_sends_arrives() -> None:
    shares = share_out(list(range(100)), [1] * 100, 3)
    with Workers(_count, shares, error=ReplayError, what="test") as sent:
        assert sorted(sent) == list(range(100))


def test_shares_are_of_about_equal_weight() -> None:
    shares = share_out(["a", "b", "c", "d", "e"], [9, 5, 4, 3, 1], 2)
    assert shares == [["a", "d"], ["b", "c", "e"]]  # 12 and 10


def test_a_workers_error_is_raised_in_the_caller() -> None:
    with pytest.raises(ValueError, match="item 7 is odd"), \
            Workers(_fail, [[7]], error=ReplayError, what="test") as sent:
        assert list(sent) == [7]


def test_a_worker_that_died_is_an_error_not_a_wait() -> None:
    with pytest.raises(ReplayError, match=r"a test worker stopped \(exit code 3\)"), \
            Workers(_die, [[1]], error=ReplayError, what="test") as sent:
        list(sent)


def test_leaving_early_ends_every_worker() -> None:
    with Workers(_sleep, [[1], [2]], error=ReplayError, what="test") as sent:
        pids = [next(sent), next(sent)]
    for pid in pids:
        assert not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
