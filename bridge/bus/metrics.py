"""Health out: a fleet's numbers on a Prometheus endpoint (``--metrics ADDR:PORT``).

Each thing is counted once, by whoever knows it: a unit's bridge serves the numbers its
Status message carries (``status_metrics``, read at each scrape from the last Status,
sent once a second), the recorder only its own view of the units, under its own names
(``recorder_metrics``: what it archived, when it last heard from each), so that one
scrape job over bridges and recorder sums each unit once, and a dead bridge's unit
vanishes with it instead of living on in the recorder. Latencies are histograms
(``Latencies``) of the messages a bridge stamps with their publish time, one put in
``bridge.bus.publish.STAMP_EVERY``, so that no other read pays for them. Names and
labels follow Prometheus' conventions: counters end in ``_total``, times are in seconds,
ratios are ratios, every per-unit series has a ``unit`` label.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import TYPE_CHECKING, Protocol

from prometheus_client import Histogram, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector, CollectorRegistry

from bridge.bus.gx3_pb2 import Status
from bridge.exceptions import MetricsError

if TYPE_CHECKING:
    from wsgiref.simple_server import WSGIServer

__all__ = ["LATENCIES", "LATENCY_BUCKETS_S", "ArchivedUnit", "Health", "Latencies", "MetricsServer",
           "parse_address", "recorder_metrics", "status_metrics"]

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
#: Upper bounds of the latency histograms' buckets, seconds: a read's publication
#: (~0.1 ms) to a sample's archiving across a network (~10 ms to seconds).
LATENCY_BUCKETS_S = (0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05,
                     0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0)


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
            f"{prefix}_clock_drift_ratio", "The unit's clock rate error against the host's, "
            "a ratio (positive: fast; 1e-6 is 1 ppm); absent until the model has measured "
            "it.", labels=["unit"]),
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
        current = Status.State.Name(s.state)
        for state in states:
            gauges["state"].add_metric([s.unit, state.removeprefix("STATE_").lower()],
                                       float(state == current))
        gauges["status_time"].add_metric([s.unit], s.time_ns / 1e9)
        if s.clock_offset_ns:  # 0 until the unit's clock is modelled
            gauges["offset"].add_metric([s.unit], s.clock_offset_ns / 1e9)
            gauges["spread"].add_metric([s.unit], s.clock_spread_ns / 1e9)
            if s.clock_drift_ppm:  # exactly 0 until the rate is measured
                gauges["drift"].add_metric([s.unit], s.clock_drift_ppm * 1e-6)
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

    @property
    def heard_ns(self) -> int:
        """When its last message was received (host ns; 0: none yet)."""


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
                              "is on the network, as the recorder sees it.", labels=["unit"])
    heard = GaugeMetricFamily(f"{prefix}_recorder_unit_last_heard_timestamp_seconds",
                              "When the recorder last received a message of the unit "
                              "(Unix seconds; absent before the first).", labels=["unit"])
    for row in rows:
        samples.add_metric([row.unit], float(row.samples))
        size.add_metric([row.unit], float(row.bytes))
        alive.add_metric([row.unit], float(row.alive))
        if row.heard_ns:
            heard.add_metric([row.unit], row.heard_ns / 1e9)
    yield from (samples, size, alive, heard)
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


#: The latency histograms: what each is kept for -> its name and what it measures.
LATENCIES = {
    "publish": ("gx3_publish_latency_seconds",
                "From the receipt of a read of the unit to the return of the put of its "
                "samples on Zenoh, on the bridge host's clock (one put in 16)."),
    "archive": ("gx3_recorder_archive_latency_seconds",
                "From a sample's put by its bridge (on the bridge host's clock) to its "
                "hand-over to the archive's writer (on the recorder's; one put in 16)."),
}


class Latencies:
    """A latency histogram per unit, of the messages observed (a sample of them).

    Prometheus' own histogram (``_bucket``, ``_sum``, ``_count``), buckets
    ``LATENCY_BUCKETS_S``. A latency below zero (two hosts' clocks apart) counts as 0, so
    that ``_sum`` stays a counter.

    Args:
        kind: Which of ``LATENCIES``: ``publish`` (a bridge's) or ``archive`` (a
            recorder's).
    """

    def __init__(self, kind: str) -> None:
        name, text = LATENCIES[kind]
        self._histogram = Histogram(name, text, ["unit"], buckets=LATENCY_BUCKETS_S,
                                    registry=None)

    def observe(self, unit: str, seconds: Iterable[float]) -> None:
        """Count latencies of a unit's messages.

        Args:
            unit: The unit.
            seconds: Each message's latency.
        """
        child = self._histogram.labels(unit)
        for value in seconds:
            child.observe(max(value, 0.0))

    def collect(self) -> Iterable[Metric]:
        """The histogram's family (at each scrape)."""
        return self._histogram.collect()


class Health(Collector):
    """What a process serves to Prometheus, read at each scrape.

    Args:
        extra: More families, read at each scrape (the recorder's own numbers).
        latencies: The latency histograms it keeps (of ``LATENCIES``).

    Attributes:
        latencies: Each histogram kept, by kind.
    """

    def __init__(self, extra: Callable[[], Iterable[Metric]] | None = None,
                 latencies: Iterable[str] = ()) -> None:
        self._statuses: dict[str, Status] = {}
        self._lock = threading.Lock()
        self._extra = extra
        self.latencies = {kind: Latencies(kind) for kind in latencies}

    def status(self, status: Status) -> None:
        """Keep a unit's latest Status (the bridge's, once a second).

        Args:
            status: The message.
        """
        with self._lock:
            self._statuses[status.unit] = status

    def collect(self) -> Iterator[Metric]:
        """The families, for Prometheus' client (at each scrape).

        Yields:
            Each family.
        """
        with self._lock:
            statuses = list(self._statuses.values())
        if statuses:
            yield from status_metrics(statuses)
        for latencies in self.latencies.values():
            yield from latencies.collect()
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
