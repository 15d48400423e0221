"""Health out: a fleet's numbers on a Prometheus endpoint (``--metrics ADDR:PORT``).

Both the bridge and the recorder serve the numbers each unit's Status message carries
(the bridge from the Status it publishes, the recorder from the latest one it archived
of each unit), through one function, so that the two never disagree on a name or a
meaning; the recorder adds what it archived. The values are read when Prometheus
scrapes, from the last Status (sent once a second): nothing is added to a read's path.
Names and labels follow Prometheus' conventions: counters end in ``_total``, times are
in seconds, every per-unit series has a ``unit`` label.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import TYPE_CHECKING, Protocol

from prometheus_client import start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

from bridge.bus.gx3_pb2 import Status
from bridge.exceptions import MetricsError

if TYPE_CHECKING:
    from wsgiref.simple_server import WSGIServer

__all__ = ["ArchivedUnit", "Health", "MetricsServer", "parse_address", "recorder_metrics",
           "status_metrics"]

#: Counters of a unit's Status: (metric name without the prefix, Status field, help).
_COUNTERS = (
    ("samples", "samples", "Samples published."),
    ("records_lost", "dropped", "Records missing from gaps in the unit's timer."),
    ("checksum_failures", "checksum_failures", "Records whose checksum failed."),
    ("implausible_records", "implausible", "Checksum matches refused as out of range."),
    ("skipped_bytes", "bytes_skipped", "Bytes discarded while resynchronising."),
    ("resyncs", "resyncs", "Times the byte stream was resynchronised."),
    ("reconnects", "reconnects", "Times the unit was brought up again."),
    ("timer_glitches", "glitches", "Timer jumps that are neither gaps nor resets."),
)


def status_metrics(statuses: Iterable[Status], prefix: str = "gx3") -> Iterator[Metric]:
    """The metric families of units' latest Status messages.

    Args:
        statuses: Each unit's latest Status.
        prefix: The first part of every metric's name.

    Yields:
        One family per number, a sample per unit.
    """
    items = list(statuses)
    for name, attribute, text in _COUNTERS:
        family = CounterMetricFamily(f"{prefix}_{name}", text, labels=["unit"])
        for s in items:
            family.add_metric([s.unit], float(getattr(s, attribute)))
        yield family
    gauges = {
        "sample_rate_hertz": GaugeMetricFamily(
            f"{prefix}_sample_rate_hertz", "Samples a second over the last seconds.",
            labels=["unit"]),
        "connected": GaugeMetricFamily(
            f"{prefix}_unit_connected", "1 while the unit streams or is polled.",
            labels=["unit"]),
        "state": GaugeMetricFamily(
            f"{prefix}_unit_state", "1 for the unit's state, 0 for the others.",
            labels=["unit", "state"]),
        "status_time": GaugeMetricFamily(
            f"{prefix}_status_timestamp_seconds",
            "When the unit's latest status was sent (its age tells a silent bridge).",
            labels=["unit"]),
        "offset": GaugeMetricFamily(
            f"{prefix}_clock_offset_seconds", "The unit's clock model: host time (Unix "
            "seconds) at its timer's zero; absent until modelled.", labels=["unit"]),
        "drift": GaugeMetricFamily(
            f"{prefix}_clock_drift_ppm", "The unit's clock rate error against the host's "
            "(positive: fast); absent until the model has measured it.", labels=["unit"]),
        "spread": GaugeMetricFamily(
            f"{prefix}_clock_spread_seconds", "The clock model's quality: median latency "
            "of arrivals above it.", labels=["unit"]),
        "uncertainty": GaugeMetricFamily(
            f"{prefix}_time_uncertainty_seconds", "The most the unit's latest time_ns can "
            "be off by, as its reads bound it; absent where not known (a UART).",
            labels=["unit"]),
        "synchronised": GaugeMetricFamily(
            f"{prefix}_host_clock_synchronised", "1 if the bridge host's clock is "
            "disciplined (chrony, ntpd, PTP), as its kernel says.", labels=["unit", "host"]),
        "max_error": GaugeMetricFamily(
            f"{prefix}_host_clock_max_error_seconds", "The bridge host clock's maximum "
            "error, as its kernel estimates it.", labels=["unit", "host"]),
    }
    states = [n for n in Status.State.keys() if n != "STATE_UNSPECIFIED"]  # noqa: SIM118
    for s in items:
        gauges["sample_rate_hertz"].add_metric([s.unit], s.samples_per_s)
        gauges["connected"].add_metric([s.unit], float(s.connected))
        current = Status.State.Name(s.state)
        for state in states:
            gauges["state"].add_metric([s.unit, state.removeprefix("STATE_").lower()],
                                       float(state == current))
        gauges["status_time"].add_metric([s.unit], s.time_ns / 1e9)
        if s.clock_offset_ns:  # 0 until the unit's clock is modelled
            gauges["offset"].add_metric([s.unit], s.clock_offset_ns / 1e9)
            gauges["spread"].add_metric([s.unit], s.clock_spread_ns / 1e9)
            if s.clock_drift_ppm:  # exactly 0 until the rate is measured
                gauges["drift"].add_metric([s.unit], s.clock_drift_ppm)
            if s.time_uncertainty_ns:  # 0: not known
                gauges["uncertainty"].add_metric([s.unit], s.time_uncertainty_ns / 1e9)
        if s.host_clock.known:
            host = s.host_clock.host
            gauges["synchronised"].add_metric([s.unit, host], float(s.host_clock.synchronised))
            gauges["max_error"].add_metric([s.unit, host], s.host_clock.maximum_error_ns / 1e9)
    yield from gauges.values()


class ArchivedUnit(Protocol):
    """What ``recorder_metrics`` reads of each unit a recorder archives.

    A recorder's rows (``bridge.recorder.UnitRow``) are such; ``bus`` sits below the
    recorder, so it names what it reads instead of importing the row.
    """

    @property
    def unit(self) -> str:
        """The unit's name."""

    @property
    def samples(self) -> int:
        """Samples archived."""

    @property
    def bytes(self) -> int:
        """Bytes of its messages archived."""

    @property
    def alive(self) -> bool:
        """Whether its bridge is on the network."""


def recorder_metrics(rows: Iterable[ArchivedUnit], written: int, lost: int,
                     prefix: str = "gx3", *, archive_bytes: int | None = None,
                     unarchived: Mapping[str, int] | None = None) -> Iterator[Metric]:
    """The metric families of what a recorder archived.

    Args:
        rows: Its units' rows (``Recorder.snapshot``).
        written: Messages written into the archive.
        lost: Samples Zenoh reported lost in transit.
        prefix: The first part of every metric's name.
        archive_bytes: Bytes in the archive's files so far (every part); None: not known.
        unarchived: Messages not archived, by reason (``lost``, ``rejected``, ``shed``:
            the events that account for them); None: not known.

    Yields:
        One family per number.
    """
    samples = CounterMetricFamily(f"{prefix}_recorder_samples", "Samples archived.",
                                  labels=["unit"])
    size = CounterMetricFamily(f"{prefix}_recorder_bytes", "Bytes of the unit's messages "
                               "archived.", labels=["unit"])
    alive = GaugeMetricFamily(f"{prefix}_recorder_unit_alive", "1 while the unit's bridge "
                              "is on the network.", labels=["unit"])
    for row in rows:
        samples.add_metric([row.unit], float(row.samples))
        size.add_metric([row.unit], float(row.bytes))
        alive.add_metric([row.unit], float(row.alive))
    yield from (samples, size, alive)
    yield CounterMetricFamily(f"{prefix}_recorder_messages_written",
                              "Messages written into the archive.", value=float(written))
    yield CounterMetricFamily(f"{prefix}_recorder_samples_lost_in_transit",
                              "Samples Zenoh reported lost before they reached the recorder.",
                              value=float(lost))
    if archive_bytes is not None:
        yield CounterMetricFamily(f"{prefix}_recorder_written_bytes", "Bytes written into "
                                  "the archive's files (every part; compressed, as on disk).",
                                  value=float(archive_bytes))
    if unarchived is not None:
        family = CounterMetricFamily(
            f"{prefix}_recorder_messages_unarchived", "Messages not archived, by reason: "
            "lost (a gap in a sequence), rejected (not a gx3 message), shed (the buffer was "
            "full).", labels=["reason"])
        for reason, count in sorted(unarchived.items()):
            family.add_metric([reason], float(count))
        yield family


class Health(Collector):
    """What a process serves to Prometheus: its units' latest Status, and ``extra``.

    Args:
        pull: Reads the units' latest Status messages at each scrape (the recorder's);
            None: they are handed over with ``status`` (the bridge's).
        extra: More families, read at each scrape (the recorder's own numbers).
    """

    def __init__(self, pull: Callable[[], Iterable[Status]] | None = None,
                 extra: Callable[[], Iterable[Metric]] | None = None) -> None:
        self._statuses: dict[str, Status] = {}
        self._lock = threading.Lock()
        self._pull, self._extra = pull, extra

    def status(self, status: Status) -> None:
        """Keep a unit's latest Status (the bridge's, once a second).

        Args:
            status: The message.
        """
        with self._lock:
            self._statuses[status.unit] = status

    def statuses_from(self, statuses: Iterable[Status]) -> None:
        """Keep several units' latest Status messages at once.

        Args:
            statuses: The messages.
        """
        with self._lock:
            self._statuses.update((s.unit, s) for s in statuses)

    def collect(self) -> Iterator[Metric]:
        """The families, for Prometheus' client (at each scrape).

        Yields:
            Each family.
        """
        if self._pull is not None:
            self.statuses_from(self._pull())
        with self._lock:
            statuses = list(self._statuses.values())
        yield from status_metrics(statuses)
        if self._extra is not None:
            yield from self._extra()


def parse_address(text: str) -> tuple[str, int]:
    """``ADDR:PORT`` (``:PORT`` for every interface) as a host and a port.

    Args:
        text: What ``--metrics`` was given.

    Returns:
        The address to listen on, and the port.

    Raises:
        MetricsError: Not an address and a port.
    """
    host, colon, port = text.rpartition(":")
    if not colon or not port.isdigit() or not 0 < int(port) < 65_536:
        raise MetricsError(f"--metrics {text!r}: give ADDR:PORT, such as 127.0.0.1:9464, or "
                           ":9464 for every interface")
    return host.strip("[]") or "0.0.0.0", int(port)


class MetricsServer:
    """Prometheus' endpoint (``/metrics``) for a ``Health``, on a thread of its own.

    Args:
        address: ``ADDR:PORT`` to listen on.
        health: What it serves.

    Raises:
        MetricsError: The address is not one, or its port cannot be listened on.
    """

    def __init__(self, address: str, health: Health) -> None:
        host, port = parse_address(address)
        registry = CollectorRegistry(auto_describe=False)
        registry.register(health)
        try:
            started: tuple[WSGIServer, threading.Thread] = start_http_server(
                port, host, registry)
        except OSError as exc:
            raise MetricsError(f"--metrics {address}: cannot listen there ({exc.strerror}); "
                               "give a free port, or stop what holds it") from None
        self._server, self._thread = started
        self.address = address

    def close(self) -> None:
        """Stop serving, and wait for the server's thread."""
        self._server.shutdown()
        self._server.server_close()
        self._thread.join()

    def __enter__(self) -> MetricsServer:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()
