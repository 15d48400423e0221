"""Keep Zenoh's per-sample routing cheap on a session that receives from many units.

Zenoh (1.10) routes a sample on a key that is not declared on the receiving session by
searching every token and queryable of every unit: ~14 us a sample at 100 units, more
than a core at 1 kHz. A key declared on the session (``declare_keyexpr``) has its route
cached: ~1.5 us (``bench/bench_recorder.py``). Why: docs/design/architecture.md.

``PublisherKeys`` watches the publishers' tokens under a key expression and declares
each publisher's key as it appears, before its first sample arrives. The tokens also
tell which key a publisher (a Zenoh entity, as a sample-miss report names it) puts on,
and when two live publishers put on one key: two bridges under one unit name.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Any

import zenoh

#: What zenoh.ext puts between a publisher's key and its liveliness token.
ADVANCED_PUBLISHER = "/@adv/pub/"


class PublisherKeys:
    """Declare on a session the key of every advanced publisher matching a key expression.

    The keys stay declared for as long as this object is open (``close`` undeclares
    them).

    Args:
        session: The receiving session.
        key: The key expression the publishers put on (``gx3/*/imu``).
        on_conflict: ``on_conflict(key, sessions)`` hears when a publisher appears on a
            key that a publisher of another session still holds (the Zenoh ids of both,
            sorted).
    """

    def __init__(self, session: zenoh.Session, key: str,
                 on_conflict: Callable[[str, list[str]], None] | None = None) -> None:
        self._session = session
        self._lock = threading.Lock()
        self._declared: dict[str, Any] = {}
        self._keys: dict[tuple[str, int], str] = {}  # (zid, eid) -> key it puts on
        self._live: dict[str, set[tuple[str, int]]] = {}
        self._on_conflict = on_conflict
        self._closed = False
        self._tokens = session.liveliness().declare_subscriber(
            f"{key}{ADVANCED_PUBLISHER}**", self._on_token, history=True)

    @property
    def keys(self) -> list[str]:
        """The keys declared so far, sorted."""
        with self._lock:
            return sorted(self._declared)

    def key_of(self, zid: str, eid: int) -> str | None:
        """The key a publisher puts on.

        Args:
            zid: The Zenoh id of its session.
            eid: Its entity id in that session.

        Returns:
            The key, or None if its token was not seen.
        """
        with self._lock:
            return self._keys.get((zid, eid))

    def _on_token(self, sample: zenoh.Sample) -> None:
        key, _, rest = str(sample.key_expr).partition(ADVANCED_PUBLISHER)
        zid, _, eid = rest.partition("/")
        source = (zid, int(eid.partition("/")[0] or -1))
        with self._lock:
            live = self._live.setdefault(key, set())
            if sample.kind != zenoh.SampleKind.PUT:
                live.discard(source)
                return  # a publisher that leaves may come back: its key stays declared
            live.add(source)
            self._keys[source] = key
            sessions = sorted({z for z, _ in live})
            if not self._closed and key not in self._declared:
                with contextlib.suppress(zenoh.ZError):  # the session is closing
                    self._declared[key] = self._session.declare_keyexpr(key)
        if len(sessions) > 1 and self._on_conflict is not None:
            self._on_conflict(key, sessions)

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
