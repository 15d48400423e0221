"""Work shared out among processes, what each sends streamed back to the caller as it comes."""

from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from queue import Empty
from types import TracebackType
from typing import Any, Generic, TypeVar

from bridge.exceptions import Gx3Error

S = TypeVar("S")  # what one worker is given
M = TypeVar("M")  # what workers send back
T = TypeVar("T")

#: Messages the workers may have waiting for the caller: memory stays flat however fast
#: they are.
QUEUED = 64
_POLL_S = 1.0  # how often a caller waiting for messages looks for a worker that died
_JOIN_S = 5.0  # a killed worker is gone at once; this only bounds a stuck kernel call
#: Ctrl-C and SIGTERM: held back while the workers start, so that one that comes then
#: reaches the caller once they have (a worker half made would print a traceback), and
#: a worker, which ignores Ctrl-C and ends at SIGTERM, has set that up before either.
_STOPS = {signal.SIGINT, signal.SIGTERM}


def share_out(items: Sequence[T], weights: Sequence[int], jobs: int) -> list[list[T]]:
    """``items`` in ``jobs`` shares of about equal weight.

    The heaviest item first, each to the lightest share so far.

    Args:
        items: The work.
        weights: What each item costs (bytes, samples), in the order of ``items``.
        jobs: How many shares.

    Returns:
        ``jobs`` lists; some are empty where there are fewer items than jobs.
    """
    shares: list[list[T]] = [[] for _ in range(jobs)]
    loads = [0] * jobs
    for item, weight in sorted(zip(items, weights, strict=True), key=lambda iw: -iw[1]):
        least = loads.index(min(loads))
        shares[least].append(item)
        loads[least] += weight
    return shares


@dataclass(frozen=True)
class _Failed:
    """A worker's error, to be raised by the caller."""

    error: Exception


@dataclass(frozen=True)
class _Finished:
    """A worker's last message: its share is done."""


class Workers(Generic[S, M]):
    """``work(share, send)`` for each share, each in a process of its own.

    Forked where the platform forks, so that a worker finds the caller's data as it was
    and nothing is pickled but what it sends; spawned elsewhere (``work`` and the shares
    must then pickle). Entering starts the processes (before the caller starts threads
    of its own: a process with threads forks badly) and gives what they ``send``, as it
    comes, until every one has finished. A bounded queue carries it, so memory stays
    flat however fast they are. A worker ignores Ctrl-C (the caller's to handle), ends
    at SIGTERM, and ends itself once the caller is gone (killed), which would never read
    what it sends. Leaving ends every worker still running, however the block ends (an
    error, Ctrl-C anywhere), so none is left behind or waited on for ever.

    Args:
        work: Does one share, handing each result to ``send``; at module level, or a
            ``functools.partial`` of a function there (it may have to pickle).
        shares: One per process.
        error: What a worker's error that does not pickle, or a worker that died, is
            raised as: a ``Gx3Error`` of the caller's kind.
        what: The work in a word, for the message of a worker that died (``replay``).

    Raises:
        Exception: On iterating: what a worker raised (``error`` where it does not pickle).
        Gx3Error: On iterating: ``error``, when a worker died (killed, out of memory).
    """

    def __init__(self, work: Callable[[S, Callable[[M], None]], None], shares: Sequence[S], *,
                 error: type[Gx3Error], what: str) -> None:
        self._error, self._what = error, what
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("fork" if "fork" in methods else None)
        self._queue: multiprocessing.Queue[M | _Failed | _Finished] = context.Queue(QUEUED)
        self._processes = [context.Process(target=_run, daemon=True, args=(
            work, share, self._queue, os.getpid(), error)) for share in shares]

    def __enter__(self) -> Iterator[M]:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)
        try:
            for process in self._processes:
                process.start()
            signal.pthread_sigmask(signal.SIG_SETMASK, held)  # one held back comes now
        except BaseException:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
            self._end()
            raise
        return self._sent()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._end()

    def _sent(self) -> Iterator[M]:
        """What the workers send, until each has finished."""
        running = len(self._processes)
        while running:
            try:
                item = self._queue.get(timeout=_POLL_S)
            except Empty:
                dead = [p.exitcode for p in self._processes if p.exitcode not in (None, 0)]
                if dead:
                    raise self._error(f"a {self._what} worker stopped (exit code {dead[0]}); "
                                      "try again with --jobs 1") from None
                continue
            if isinstance(item, _Failed):
                raise item.error
            if isinstance(item, _Finished):
                running -= 1
            else:
                yield item

    def _end(self) -> None:
        """Kill the workers still running, and wait (a bounded time) until they are gone."""
        started = [p for p in self._processes if p.pid is not None]
        for process in started:
            if process.exitcode is None:
                process.kill()
        for process in started:
            process.join(_JOIN_S)
        self._queue.close()


def _run(work: Callable[[S, Callable[[Any], None]], None], share: S,
         queue: multiprocessing.Queue[Any], parent: int, error: type[Gx3Error]) -> None:
    """One worker: ``work`` on its share, then its error if it failed, then the end."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOPS)  # (held back while it started)
    threading.Thread(target=_end_when_orphaned, args=(parent,), daemon=True).start()
    try:
        work(share, queue.put)
    except Exception as exc:  # every error reaches the caller, to say as it would alone
        queue.put(_Failed(sendable(exc, error)))
    queue.put(_Finished())


def sendable(exc: Exception, error: type[Gx3Error]) -> Exception:
    """``exc``, or its words in an ``error``, which pickles: the queue would drop it otherwise.

    Args:
        exc: What a worker raised.
        error: The caller's kind of error.

    Returns:
        What the worker sends.
    """
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return error(f"{type(exc).__name__}: {exc}")
    return exc


def _end_when_orphaned(parent: int) -> None:
    """End a worker whose caller is gone (killed).

    Nobody will read what it sends, and it would wait on the full queue for ever.
    """
    while os.getppid() == parent:
        time.sleep(1.0)
    os._exit(1)
