"""Zenoh key expressions and encodings of gx3-bridge: the one place that spells them.

Per unit, under a prefix (default ``gx3``):

- ``gx3/<unit>/imu``      ImuSample, one per record (advanced publisher with a cache)
- ``gx3/<unit>/status``   Status, once a second
- ``gx3/<unit>/event``    Event, as things happen
- ``gx3/<unit>/info``     queryable answering the current Info
- ``gx3/<unit>/command``  queryable for operator actions (refused unless --allow-commands)
- ``gx3/<unit>/raw``      each read from the unit, with its receive time attached
  (``gx3 bridge --publish-raw``)
- ``gx3/<unit>/alive``    liveliness token, present while the bridge runs

Every message on a data key (and every info reply) carries the CRC-32 of its payload
in its attachment (layout in bridge/bus/integrity.py).

Liveliness tokens live in their own space (``session.liveliness()``), so ``alive``
never collides with published data; ``gx3/*/alive`` lists the running bridges.
``gx3/*/imu`` is every sample of the fleet.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from bridge.exceptions import BadName

PREFIX = "gx3"
_CHUNK = re.compile(r"[A-Za-z0-9_.\-]{1,64}")

ENCODINGS = {
    "imu": "application/protobuf;gx3.v1.ImuSample",
    "status": "application/protobuf;gx3.v1.Status",
    "event": "application/protobuf;gx3.v1.Event",
    "info": "application/protobuf;gx3.v1.Info",
    "raw": "application/octet-stream",
    "command": "text/plain;charset=utf-8",
}


def check_unit(name: str) -> str:
    """Check a unit name: it must be one safe key chunk.

    Args:
        name: The name.

    Returns:
        ``name``.

    Raises:
        BadName: It cannot be a chunk of a key; the message says what is allowed.
    """
    if not isinstance(name, str) or not _CHUNK.fullmatch(name):
        raise BadName(f"unit name {name!r} cannot be used in a Zenoh key: use 1-64 letters, "
                      "digits, '_', '-' or '.' (no '/', '*', '$', '?', '#', spaces), e.g. 'imu0'")
    return name


def check_prefix(prefix: str) -> str:
    """Check a key prefix: it must be one or more safe chunks joined by '/'.

    Args:
        prefix: The prefix.

    Returns:
        ``prefix``.

    Raises:
        BadName: It cannot start a key; the message says what is allowed.
    """
    if not isinstance(prefix, str) or not all(_CHUNK.fullmatch(c) for c in prefix.split("/")):
        raise BadName(f"key prefix {prefix!r} cannot be used in a Zenoh key: use chunks of "
                      "letters, digits, '_', '-' or '.' joined by '/', e.g. 'gx3' or 'lab/gx3'")
    return prefix


@dataclass(frozen=True)
class UnitKeys:
    """Every key of one unit.

    Args:
        unit: The unit's name.
        prefix: The keys' prefix.

    Raises:
        BadName: The name or the prefix cannot be used in a key.
    """

    unit: str
    prefix: str = PREFIX

    def __post_init__(self) -> None:
        check_unit(self.unit)
        check_prefix(self.prefix)

    def _key(self, leaf: str) -> str:
        return f"{self.prefix}/{self.unit}/{leaf}"

    @property
    def imu(self) -> str:
        """ImuSample, one per record: ``<prefix>/<unit>/imu``."""
        return self._key("imu")

    @property
    def status(self) -> str:
        """Status, once a second: ``<prefix>/<unit>/status``."""
        return self._key("status")

    @property
    def event(self) -> str:
        """Event, as things happen: ``<prefix>/<unit>/event``."""
        return self._key("event")

    @property
    def info(self) -> str:
        """The queryable answering the current Info: ``<prefix>/<unit>/info``."""
        return self._key("info")

    @property
    def command(self) -> str:
        """The queryable for operator actions: ``<prefix>/<unit>/command``."""
        return self._key("command")

    @property
    def raw(self) -> str:
        """Each read from the unit, its receive time attached: ``<prefix>/<unit>/raw``."""
        return self._key("raw")

    @property
    def alive(self) -> str:
        """The liveliness token, present while the bridge runs: ``<prefix>/<unit>/alive``."""
        return self._key("alive")


def fleet(leaf: str, prefix: str = PREFIX) -> str:
    """The key expression matching ``leaf`` of every unit, e.g. ``gx3/*/imu``.

    Args:
        leaf: ``imu``, ``status``, ``event``, ``info``, ``command``, ``raw`` or ``alive``.
        prefix: The keys' prefix.

    Returns:
        ``<prefix>/*/<leaf>``.

    Raises:
        BadName: An unknown leaf or a prefix that cannot start a key.
    """
    if leaf not in ENCODINGS and leaf != "alive":
        raise BadName(f"unknown key leaf {leaf!r}; known: {', '.join([*ENCODINGS, 'alive'])}")
    return f"{check_prefix(prefix)}/*/{leaf}"


def unit_of(key: str, prefix: str = PREFIX) -> str:
    """The unit name in a key ``<prefix>/<unit>/<leaf>``.

    Args:
        key: The key.
        prefix: The keys' prefix.

    Returns:
        The unit's name.

    Raises:
        BadName: The key is not of that form.
    """
    head = prefix + "/"
    rest = key[len(head):] if key.startswith(head) else ""
    unit = rest.split("/", 1)[0]
    if not rest or "/" not in rest:
        raise BadName(f"key {key!r} is not of the form {prefix}/<unit>/<leaf>")
    return unit
