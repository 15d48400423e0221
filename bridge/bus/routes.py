"""Keep Zenoh's per-sample routing cheap on a session that receives from many units.

An advanced publisher declares its liveliness token and cache queryable *under* its
key (``gx3/u1/imu/@adv/pub/...``). On the receiving session that puts a node for
``gx3/u1/imu`` in Zenoh's key tree that has no routing context of its own, and Zenoh
(1.10) then searches the whole tree, every token and queryable of every unit, once
per sample. Measured on 100 units at 1 kHz: ~14 us of Zenoh's receive threads per
sample, more than one core, and the publishers back up. A key declared on the
session (``declare_keyexpr``) gets that context, its route is cached, and the cost
falls to ~1.5 us a sample (``bench/bench_recorder.py``).

``PublisherKeys`` watches the publishers' tokens under a key expression and declares
each publisher's key as it appears, before its first sample arrives.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any

import zenoh

#: What zenoh.ext puts between a publisher's key and its liveliness token.
ADVANCED_PUBLISHER = "/@adv/pub/"


class PublisherKeys:
    """Declare on ``session`` the key of every advanced publisher matching ``key``,
    for as long as this object is open (``close`` undeclares them)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._session = session
        self._lock = threading.Lock()
        self._declared: dict[str, Any] = {}
        self._closed = False
        self._tokens = session.liveliness().declare_subscriber(
            f"{key}{ADVANCED_PUBLISHER}**", self._on_token, history=True)

    @property
    def keys(self) -> list[str]:
        with self._lock:
            return sorted(self._declared)

    def _on_token(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return  # a publisher that leaves may come back: its key stays declared
        key = str(sample.key_expr).split(ADVANCED_PUBLISHER, 1)[0]
        with self._lock:
            if self._closed or key in self._declared:
                return
            with contextlib.suppress(zenoh.ZError):  # the session is closing: nothing to route
                self._declared[key] = self._session.declare_keyexpr(key)

    def close(self) -> None:
        """Stop watching and undeclare every key; safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            declared = list(self._declared.values())
            self._declared.clear()
        self._tokens.undeclare()
        for keyexpr in declared:
            with contextlib.suppress(zenoh.ZError):  # a session already closed
                self._session.undeclare(keyexpr)
