"""`--metrics`: a bridge's and a recorder's health as Prometheus reads it.

Real processes on an emulated unit, scraped over HTTP and parsed with Prometheus' own
client parser; then a real Prometheus server (Debian's, unpacked by .ci/run) scrapes a
bridge and is asked, through its HTTP API, for the rate of samples. The Grafana
dashboard is checked against the metrics exported.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import zenoh
from prometheus_client.parser import text_string_to_metric_families

from bridge.bus.gx3_pb2 import HostClock, Status
from bridge.bus.metrics import (
    Health,
    MetricsServer,
    parse_address,
    recorder_metrics,
    status_metrics,
)
from bridge.exceptions import MetricsError
from bridge.recorder.units import UnitRow
from bridge.sim.serve import Simulator
from tests.helpers.processes import GX3, bridge_process, recorder
from tests.helpers.tools import tool
from tests.helpers.units import STATIC_UNIT
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config

DASHBOARD = Path(__file__).resolve().parent.parent / "configs" / "grafana" / "gx3-fleet.json"


def scrape(port: int) -> dict[str, dict[tuple[tuple[str, str], ...], float]]:
    """``/metrics`` of a process: each sample's value by name and labels (none if down)."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as reply:
            text = reply.read().decode()
    except (urllib.error.URLError, ConnectionError):
        return {}
    out: dict[str, dict[tuple[tuple[str, str], ...], float]] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out.setdefault(sample.name, {})[tuple(sorted(sample.labels.items()))] = sample.value
    return out


COUNTERS = ("samples", "dropped", "checksum_failures", "resyncs", "reconnects")
SCRAPED = ("gx3_samples_total", "gx3_records_lost_total", "gx3_checksum_failures_total",
           "gx3_resyncs_total", "gx3_reconnects_total")


def test_a_bridge_and_a_recorder_serve_the_units_health(tmp_path: Path) -> None:
    """The bridge's numbers are those of the Status it publishes; the recorder's, what
    it wrote."""
    endpoint, watch = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    bridge_port, recorder_port = free_port(), free_port()
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    watch_cfg = zenoh_config(tmp_path / "watch.json5", listen=[watch])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint, watch])
    proc = recorder(tmp_path / "fleet.mcap", rec_cfg, "--metrics",
                    f"127.0.0.1:{recorder_port}")
    unit = (("unit", "m1"),)
    statuses: list[Status] = []

    def counters() -> tuple[float, ...] | None:
        """The scraped counters, if they are those of a Status seen on Zenoh."""
        got = scrape(bridge_port)
        scraped = tuple(got.get(name, {}).get(unit, -1.0) for name in SCRAPED)
        published = {tuple(float(getattr(s, c)) for c in COUNTERS) for s in list(statuses)}
        return scraped if scraped in published else None

    try:
        with Simulator([STATIC_UNIT], "pty") as sim, \
                zenoh.open(zenoh.Config.from_file(str(watch_cfg))) as session:
            sub = session.declare_subscriber(
                "gx3/m1/status",
                lambda sample: statuses.append(Status.FromString(sample.payload.to_bytes())))
            with bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "m1", "--metrics",
                                f"127.0.0.1:{bridge_port}"):
                wait_for(lambda: scrape(bridge_port).get("gx3_samples_total", {})
                         .get(unit, 0) >= 200, what="the bridge's samples on /metrics")
                first = scrape(bridge_port)["gx3_samples_total"][unit]
                wait_for(lambda: scrape(bridge_port)["gx3_samples_total"][unit] > first,
                         what="the counter to rise")
                # the same numbers as a Status the bridge published (a scrape between
                # two Status messages can be one behind those seen: retried)
                wait_for(lambda: counters() is not None,
                         what="the scraped counters to be those of a published Status")
                bridge, latest = scrape(bridge_port), statuses[-1]
                wait_for(lambda: scrape(recorder_port).get("gx3_recorder_samples_total", {})
                         .get(unit, 0) >= 200, what="the recorder's archived samples")
                size = scrape(recorder_port)["gx3_recorder_written_bytes_total"][()]
                wait_for(lambda: scrape(recorder_port)["gx3_recorder_written_bytes_total"][()]
                         > size, what="the archive's bytes to grow")
                archived = scrape(recorder_port)
            sub.undeclare()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert proc.returncode == 0
    # within a few Status messages (one a second) of the last one seen on Zenoh
    assert abs(bridge["gx3_samples_total"][unit] - latest.samples) <= 500
    assert abs(bridge["gx3_sample_rate_hertz"][unit] - latest.samples_per_s) <= 30
    assert abs(bridge["gx3_clock_offset_seconds"][unit] - latest.clock_offset_ns / 1e9) < 0.1
    # Unix seconds at the unit's timer's zero: the emulated unit powered up in this test
    assert abs(bridge["gx3_clock_offset_seconds"][unit] - time.time()) < 300
    assert bridge["gx3_unit_state"][(("state", "streaming"), *unit)] == 1.0
    assert sum(v for k, v in bridge["gx3_unit_state"].items() if ("unit", "m1") in k) == 1.0
    assert bridge["gx3_unit_connected"][unit] == 1.0
    assert 80 <= bridge["gx3_sample_rate_hertz"][unit] <= 120  # a 100 Hz unit
    assert bridge["gx3_records_lost_total"][unit] == 0.0
    assert unit in bridge["gx3_clock_spread_seconds"]
    assert unit in bridge["gx3_clock_drift_ppm"]
    synced = {dict(k)["unit"]: v for k, v in bridge["gx3_host_clock_synchronised"].items()}
    assert synced["m1"] in (0.0, 1.0)
    # the recorder serves the same names from the Status it archived, and what it wrote
    assert archived["gx3_samples_total"][unit] <= bridge["gx3_samples_total"][unit]
    assert archived["gx3_recorder_samples_total"][unit] >= 200
    assert archived["gx3_recorder_unit_alive"][unit] == 1.0
    assert archived["gx3_recorder_messages_written_total"][()] >= 200
    assert archived["gx3_recorder_bytes_total"][unit] > 0
    assert archived["gx3_recorder_written_bytes_total"][()] > 1000
    unarchived = {dict(k)["reason"]: v
                  for k, v in archived["gx3_recorder_messages_unarchived_total"].items()}
    assert unarchived == {"lost": 0.0, "rejected": 0.0, "shed": 0.0}
    assert archived["gx3_recorder_samples_lost_in_transit_total"][()] == 0.0


def test_a_busy_port_is_one_line_and_nothing_is_made(tmp_path: Path) -> None:
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        for args in (["bridge", "--port", "/dev/null-gx3", "--unit", "x"],
                     ["record", "-o", str(tmp_path / "never.mcap")]):
            done = subprocess.run([GX3, *args, "--metrics", f"127.0.0.1:{port}"],
                                  capture_output=True, text=True, timeout=60, check=False)
            assert done.returncode == 2, done.stderr
            assert done.stderr.count("\n") == 1 and "cannot listen there" in done.stderr
        assert not (tmp_path / "never.mcap").exists()
    bad = subprocess.run([GX3, "bridge", "--port", "/dev/null-gx3", "--metrics", "9464"],
                         capture_output=True, text=True, timeout=60, check=False)
    assert bad.returncode == 2 and "give ADDR:PORT" in bad.stderr


def test_the_server_lets_its_port_go_when_closed() -> None:
    """In a process that goes on (a library's caller), closing frees the port."""
    port = free_port()
    health = Health()
    health.status(Status(unit="c1", samples=7, state=Status.STREAMING))
    with MetricsServer(f"127.0.0.1:{port}", health):
        assert scrape(port)["gx3_samples_total"][(("unit", "c1"),)] == 7.0
        try:
            MetricsServer(f"127.0.0.1:{port}", health)
            raise AssertionError("a second server took a busy port")
        except MetricsError as exc:
            assert "cannot listen there" in str(exc)
    assert scrape(port) == {}
    with MetricsServer(f"127.0.0.1:{port}", health):  # free again
        assert scrape(port)["gx3_samples_total"][(("unit", "c1"),)] == 7.0
    for bad in ("9464", "host:", "host:99999", "127.0.0.1:x"):
        try:
            parse_address(bad)
            raise AssertionError(f"{bad!r} was taken")
        except MetricsError:
            pass
    assert parse_address(":9464") == ("0.0.0.0", 9464)
    assert parse_address("[::1]:9464") == ("::1", 9464)


def test_prometheus_scrapes_a_bridge_and_queries_its_rate(tmp_path: Path) -> None:
    prometheus = tool("prometheus", "prometheus")
    bridge_port, web_port = free_port(), free_port()
    config = tmp_path / "prometheus.yml"
    config.write_text(
        "global: {scrape_interval: 1s, evaluation_interval: 1s}\n"
        "scrape_configs:\n"
        f"  - {{job_name: gx3, static_configs: [{{targets: ['127.0.0.1:{bridge_port}']}}]}}\n")
    cfg = zenoh_config(tmp_path / "bridge.json5", listen=[f"tcp/127.0.0.1:{free_port()}"])
    server = subprocess.Popen([prometheus, f"--config.file={config}",
                               f"--web.listen-address=127.0.0.1:{web_port}",
                               f"--storage.tsdb.path={tmp_path / 'tsdb'}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    def rate() -> float:
        query = urllib.parse.urlencode({"query": 'rate(gx3_samples_total{unit="p1"}[10s])'})
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/api/v1/query?{query}",
                                        timeout=5) as reply:
                result = json.load(reply)["data"]["result"]
        except (urllib.error.URLError, ConnectionError):
            return 0.0
        return float(result[0]["value"][1]) if result else 0.0

    try:
        with Simulator([STATIC_UNIT], "pty") as sim, \
                bridge_process(sim.endpoints[0], cfg, "--unit", "p1", "--metrics",
                               f"127.0.0.1:{bridge_port}"):
            # the first window holds the bring-up; a steady one, the unit's 100 Hz
            wait_for(lambda: rate() >= 50, timeout=90, what="Prometheus to see samples flow")
            seen = rate()
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=30)
    assert 50 <= seen <= 150, seen  # a 100 Hz unit


def test_the_dashboard_shows_only_metrics_we_export() -> None:
    """Every metric a panel queries is one a bridge or a recorder serves."""
    status = Status(unit="u", clock_offset_ns=1, clock_drift_ppm=1.0,
                    host_clock=HostClock(known=True, host="h"))
    families = [*status_metrics([status]), *recorder_metrics(
        [UnitRow(unit="u", alive=True, rate=1.0, samples=1, dropped=0, checksum_failures=0,
                 resyncs=0, reconnects=0, offset_ms=None, drift_ppm=None, recorded_s=1.0,
                 bytes=1, joined=1)], 1, 0, archive_bytes=1, unarchived={"shed": 0})]
    exported = {sample.name for family in families for sample in family.samples}
    dashboard = json.loads(DASHBOARD.read_text())
    panels = [p for top in dashboard["panels"] for p in [top, *top.get("panels", [])]]
    expressions = [t["expr"] for panel in panels for t in panel.get("targets", [])]
    assert len(expressions) >= 10
    for expr in expressions:
        for name in re.findall(r"\bgx3_\w+", expr):
            assert name in exported, f"{expr}: {name} is not exported"
    # what is wrong shows in red: losses, checksum failures, a unit not streaming, an
    # unsynchronised host clock, messages the recorder could not archive
    for name in ("gx3_records_lost_total", "gx3_checksum_failures_total", "gx3_unit_state",
                 "gx3_host_clock_synchronised", "gx3_recorder_messages_unarchived_total"):
        assert any(name in t["expr"] and "red" in {
            step["color"] for step in p["fieldConfig"]["defaults"]["thresholds"]["steps"]}
            for p in panels for t in p.get("targets", [])), f"{name}: no panel in red"
    assert "unit" in {v["name"] for v in dashboard["templating"]["list"]}
    assert any(p.get("repeat") == "unit" for p in panels), "no row per unit"
