"""`--metrics`: a bridge's and a recorder's health as Prometheus reads it.

Real processes on emulated units, scraped over HTTP and parsed with Prometheus' own
client parser; then a real Prometheus server (Debian's, unpacked by .ci/run) with the
monitoring guide's own configuration and alert rules scrapes two bridges and a recorder,
is asked through its HTTP API for each unit's rate of samples, and sees a bridge killed.
promtool checks the configuration, the guide's queries and the alert rules, and tests
the rules on made-up series. The Grafana dashboard is checked against the metrics
exported.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

import zenoh
from prometheus_client.parser import text_string_to_metric_families
from ruamel.yaml import YAML

from bridge.bus.gx3_pb2 import HostClock, Status
from bridge.bus.metrics import (
    LATENCIES,
    Health,
    MetricsServer,
    parse_address,
    recorder_metrics,
)
from bridge.exceptions import MetricsError
from bridge.recorder.units import UnitRow
from bridge.sim.serve import Simulator
from tests.helpers.processes import GX3, bridge_process, recorder
from tests.helpers.tools import tool
from tests.helpers.units import STATIC_UNIT, TWO_UNITS
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config

ROOT = Path(__file__).resolve().parent.parent
DASHBOARD = ROOT / "configs" / "grafana" / "gx3-fleet.json"
PROMETHEUS_CONFIG = ROOT / "configs" / "prometheus" / "prometheus.yml"
GUIDE = ROOT / "docs" / "guides" / "monitoring.md"


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
                wait_for(lambda: scrape(bridge_port).get("gx3_publish_latency_seconds_count",
                                                         {}).get(unit, 0) >= 10,
                         what="ten reads' latencies")
                bridge, latest = scrape(bridge_port), statuses[-1]
                wait_for(lambda: scrape(recorder_port).get("gx3_recorder_samples_total", {})
                         .get(unit, 0) >= 200 and scrape(recorder_port).get(
                             "gx3_recorder_archive_latency_seconds_count", {}).get(unit, 0)
                         >= 10, what="the recorder's archived samples")
                size = scrape(recorder_port)["gx3_recorder_written_bytes_total"][()]
                wait_for(lambda: scrape(recorder_port)["gx3_recorder_written_bytes_total"][()]
                         > size, what="the archive's bytes to grow")
                heard_before = time.time()
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
    assert 80 <= bridge["gx3_sample_rate_hertz"][unit] <= 120  # a 100 Hz unit
    assert bridge["gx3_records_lost_total"][unit] == 0.0
    assert unit in bridge["gx3_clock_spread_seconds"]
    # a ratio: the emulated unit's clock is 80 ppm off at most
    assert abs(bridge["gx3_clock_drift_ratio"][unit] - latest.clock_drift_ppm * 1e-6) < 20e-6
    assert abs(bridge["gx3_clock_drift_ratio"][unit]) < 1e-4
    assert "gx3_unit_connected" not in bridge  # gx3_unit_state says it
    synced = {dict(k)["unit"]: v for k, v in bridge["gx3_host_clock_synchronised"].items()}
    assert synced["m1"] in (0.0, 1.0)
    # receive -> publish, one read in 16: 100 Hz for seconds gives dozens, each well
    # under a second (a put of a record or two on loopback)
    published = bridge["gx3_publish_latency_seconds_count"][unit]
    assert published >= 10
    assert bridge["gx3_publish_latency_seconds_bucket"][(("le", "+Inf"), *unit)] == published
    assert 0 < bridge["gx3_publish_latency_seconds_sum"][unit] / published < 0.1
    # the recorder speaks for what it archived alone: none of the bridge's names
    assert not {name for name in archived if not name.startswith("gx3_recorder_")}
    assert archived["gx3_recorder_samples_total"][unit] >= 200
    heard = archived["gx3_recorder_unit_last_heard_timestamp_seconds"][unit]
    assert heard_before - 1 <= heard <= time.time()
    archive_latency = archived["gx3_recorder_archive_latency_seconds_count"][unit]
    assert archive_latency >= 10
    # handed to the writer within a pass or two of 50 ms, on one host's clock here
    assert 0 < archived["gx3_recorder_archive_latency_seconds_sum"][unit] / archive_latency < 1
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


#: The live test's scrape and evaluation interval (s): the guide's 5 s made 1 s, so that
#: rates and the alert's pending state come sooner; the rules, and so the alert's `for:`,
#: are the guide's own.
LIVE_INTERVAL_S = 1


def the_guides_prometheus(tmp_path: Path, bridges: list[int], recorder_port: int) -> Path:
    """The monitoring guide's configuration and alert rules, its targets made this test's
    and its intervals ``LIVE_INTERVAL_S``."""
    yaml = YAML()
    config = yaml.load(PROMETHEUS_CONFIG)
    for interval in ("scrape_interval", "evaluation_interval"):
        config["global"][interval] = f"{LIVE_INTERVAL_S}s"
    bridge_targets, recorder_targets = config["scrape_configs"][0]["static_configs"]
    bridge_targets["targets"] = [f"127.0.0.1:{port}" for port in bridges]
    recorder_targets["targets"] = [f"127.0.0.1:{recorder_port}"]
    for rules in config["rule_files"]:
        shutil.copy(PROMETHEUS_CONFIG.parent / rules, tmp_path / rules)
    path = tmp_path / "prometheus.yml"
    with path.open("w") as out:
        yaml.dump(config, out)
    return path


def alert_for_s(alert: str) -> float:
    """How long (s) the guide's rules want ``alert``'s condition to hold before it fires."""
    groups = YAML(typ="safe").load(PROMETHEUS_CONFIG.parent / "gx3-alerts.yml")["groups"]
    (rule,) = [r for g in groups for r in g["rules"] if r.get("alert") == alert]
    found = re.fullmatch(r"(\d+)([sm])", rule["for"])
    assert found, rule["for"]
    return int(found.group(1)) * {"s": 1, "m": 60}[found.group(2)]


def query(web_port: int, expr: str) -> list[dict[str, Any]]:
    """An instant query's result (nothing while Prometheus is not up)."""
    text = urllib.parse.urlencode({"query": expr})
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/api/v1/query?{text}",
                                    timeout=5) as reply:
            return list(json.load(reply)["data"]["result"])
    except (urllib.error.URLError, ConnectionError):
        return []


def firing(web_port: int, alert: str) -> list[dict[str, str]]:
    """The labels of each firing alert of that name."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/api/v1/alerts",
                                    timeout=5) as reply:
            alerts = json.load(reply)["data"]["alerts"]
    except (urllib.error.URLError, ConnectionError):
        return []
    return [a["labels"] for a in alerts
            if a["labels"]["alertname"] == alert and a["state"] == "firing"]


def test_the_guides_prometheus_counts_each_unit_once_and_sees_a_bridge_die(
        tmp_path: Path) -> None:
    """Two bridges and a recorder, one scrape job, the guide's config and rules: the sum
    by unit of the samples' rate is each unit's own 100 Hz (the recorder serves only
    its own names), and a bridge killed while it is scraped is down, its unit gone,
    within the guide's alert window. The config's intervals are 1 s here, not the
    guide's 5 s (the test would only wait longer); promtool checks the shipped file."""
    prometheus = tool("prometheus", "prometheus")
    bridges, recorder_port, web_port = [free_port(), free_port()], free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(tmp_path / "rec.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    server = subprocess.Popen([prometheus, "--config.file",
                               str(the_guides_prometheus(tmp_path, bridges, recorder_port)),
                               f"--web.listen-address=127.0.0.1:{web_port}",
                               f"--storage.tsdb.path={tmp_path / 'tsdb'}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    proc = recorder(tmp_path / "fleet.mcap", rec_cfg, "--metrics", f"127.0.0.1:{recorder_port}")
    rates = "sum by (unit) (rate(gx3_samples_total[1m]))"

    def per_unit(expr: str) -> dict[str, float]:
        return {r["metric"]["unit"]: float(r["value"][1]) for r in query(web_port, expr)}

    try:
        with Simulator(TWO_UNITS, "pty") as sim, \
                bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "p1", "--metrics",
                               f"127.0.0.1:{bridges[0]}"), \
                bridge_process(sim.endpoints[1], bridge_cfg, "--unit", "p2", "--metrics",
                               f"127.0.0.1:{bridges[1]}") as doomed:
            # two scrapes of each bridge's counter after its bring-up give a rate
            wait_for(lambda: len(per_unit(rates)) == 2 and min(per_unit(rates).values()) >= 50
                     and len(per_unit("gx3_recorder_samples_total")) == 2,
                     timeout=90, what="Prometheus to see both units' samples flow")
            seen, archived = per_unit(rates), per_unit(
                "sum by (unit) (rate(gx3_recorder_samples_total[1m]))")
            doomed.kill()
            killed = time.monotonic()
            wait_for(lambda: bool(firing(web_port, "Gx3BridgeDown")), timeout=90,
                     what="the guide's alert on the killed bridge")
            down = time.monotonic() - killed
            (alert,) = firing(web_port, "Gx3BridgeDown")
            gone = per_unit('gx3_unit_state{state="streaming"}')
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=30)
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=30)
    assert set(seen) == {"p1", "p2"} and all(50 <= r <= 150 for r in seen.values()), seen
    assert set(archived) == {"p1", "p2"}, archived  # the recorder's own names
    assert alert["instance"] == f"127.0.0.1:{bridges[1]}" and alert["role"] == "bridge"
    # pending at the first failed scrape (an interval at most), firing the rule's `for:`
    # later, each seen at an evaluation (an interval each), and a margin for a busy
    # machine; never before the `for:` has passed since the kill (less an interval: a
    # scrape under way at the kill is stamped when it began)
    hold = alert_for_s("Gx3BridgeDown")
    assert hold - LIVE_INTERVAL_S <= down <= hold + 3 * LIVE_INTERVAL_S + 10, down
    assert set(gone) == {"p1"}, gone  # the dead bridge's unit does not live on


def promtool(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([tool("promtool", "prometheus"), *map(str, args)],
                          capture_output=True, text=True, timeout=60, check=False)


def test_the_guides_queries_config_and_rules_pass_promtool(tmp_path: Path) -> None:
    """promtool checks the shipped configuration (and the rule file it names), and every
    query the monitoring guide shows, each as a recording rule."""
    done = promtool("check", "config", PROMETHEUS_CONFIG)
    assert done.returncode == 0 and "SUCCESS: 1 rule files found" in done.stdout, done.stdout
    queries = re.findall(r"```promql\n(.*?)```", GUIDE.read_text(), re.S)
    expressions = [line.split("  #")[0].strip() for block in queries
                   for line in block.splitlines() if line.strip()]
    assert len(expressions) >= 6
    rules = tmp_path / "queries.yml"
    YAML().dump({"groups": [{"name": "guide", "rules": [
        {"record": f"gx3:guide:{i}", "expr": e} for i, e in enumerate(expressions)]}]},
        rules)
    done = promtool("check", "rules", rules)
    assert done.returncode == 0 and f"SUCCESS: {len(expressions)} rules found" in done.stdout, \
        done.stdout + done.stderr
    for expr in expressions:
        for name in re.findall(r"\bgx3_\w+", expr):
            assert name in exported(), f"{expr}: {name} is not exported"


def test_the_alert_rules_fire_as_the_guide_says(tmp_path: Path) -> None:
    """promtool's rule tests on made-up series: a bridge down for 15 s fires, a
    recorder down fires its own alert, and a unit the recorder has not heard of for 10 s
    is told."""
    tests = tmp_path / "alerts-test.yml"
    YAML().dump({
        "rule_files": [str(PROMETHEUS_CONFIG.parent / "gx3-alerts.yml")],
        "evaluation_interval": "5s",
        "tests": [{
            "interval": "5s",
            "input_series": [
                {"series": 'up{job="gx3", role="bridge", instance="b1:9464"}',
                 "values": "1 1 0 0 0 0 0 0"},
                {"series": 'up{job="gx3", role="recorder", instance="r:9465"}',
                 "values": "1 1 1 1 0 0 0 0"},
                {"series": 'gx3_recorder_unit_last_heard_timestamp_seconds{unit="u1"}',
                 "values": "0 5 10 10 10 10 10 10"},
            ],
            "alert_rule_test": [
                {"eval_time": "20s", "alertname": "Gx3BridgeDown", "exp_alerts": []},
                {"eval_time": "25s", "alertname": "Gx3BridgeDown", "exp_alerts": [{
                    "exp_labels": {"job": "gx3", "role": "bridge", "instance": "b1:9464"},
                    "exp_annotations": {"summary": "b1:9464: the bridge does not answer; "
                                                   "its unit is not published"}}]},
                {"eval_time": "25s", "alertname": "Gx3RecorderDown", "exp_alerts": []},
                {"eval_time": "35s", "alertname": "Gx3RecorderDown", "exp_alerts": [{
                    "exp_labels": {"job": "gx3", "role": "recorder", "instance": "r:9465"},
                    "exp_annotations": {"summary": "r:9465: the recorder does not answer; "
                                                   "nothing is archived"}}]},
                {"eval_time": "20s", "alertname": "Gx3UnitNotArchived", "exp_alerts": []},
                {"eval_time": "25s", "alertname": "Gx3UnitNotArchived", "exp_alerts": [{
                    "exp_labels": {"unit": "u1"},
                    "exp_annotations": {"summary": "the recorder has heard nothing of u1 "
                                                   "for 10 s"}}]},
            ]}]}, tests)
    done = promtool("test", "rules", tests)
    assert done.returncode == 0, done.stdout + done.stderr


def exported() -> set[str]:
    """The name of every series a bridge or a recorder serves."""
    status = Status(unit="u", clock_offset_ns=1, clock_drift_ppm=1.0,
                    host_clock=HostClock(known=True, host="h"))
    health = Health(latencies=LATENCIES)
    health.status(status)
    for latencies in health.latencies.values():
        latencies.observe("u", [0.001])
    families = [*health.collect(), *recorder_metrics(
        [UnitRow(unit="u", alive=True, rate=1.0, samples=1, dropped=0, checksum_failures=0,
                 resyncs=0, reconnects=0, offset_ms=None, drift_ppm=None, recorded_s=1.0,
                 bytes=1, joined=1, heard_ns=1)], 1, 0, archive_bytes=1,
        unarchived={"shed": 0})]
    return {sample.name for family in families for sample in family.samples}


def test_the_dashboard_shows_only_metrics_we_export() -> None:
    """Every metric a panel queries is one a bridge or a recorder serves."""
    exported_names = exported()
    dashboard = json.loads(DASHBOARD.read_text())
    panels = [p for top in dashboard["panels"] for p in [top, *top.get("panels", [])]]
    expressions = [t["expr"] for panel in panels for t in panel.get("targets", [])]
    assert len(expressions) >= 10
    for expr in expressions:
        for name in re.findall(r"\bgx3_\w+", expr):
            assert name in exported_names, f"{expr}: {name} is not exported"
    # what is wrong shows in red: losses, checksum failures, a unit not streaming, an
    # unsynchronised host clock, messages the recorder could not archive
    for name in ("gx3_records_lost_total", "gx3_checksum_failures_total", "gx3_unit_state",
                 "gx3_host_clock_synchronised", "gx3_recorder_messages_unarchived_total"):
        assert any(name in t["expr"] and "red" in {
            step["color"] for step in p["fieldConfig"]["defaults"]["thresholds"]["steps"]}
            for p in panels for t in p.get("targets", [])), f"{name}: no panel in red"
    assert "unit" in {v["name"] for v in dashboard["templating"]["list"]}
    assert any(p.get("repeat") == "unit" for p in panels), "no row per unit"
