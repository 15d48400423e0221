"""configs/tls/router-acl.json5 for real: mutual TLS, and only operators may command.

A router with the shipped config (its certificate paths swapped for ones made here),
a "bridge" client serving a unit's info and command queryables and publishing its
samples, a recorder-like client, and an operator client whose certificate is named
gx3-operator. Data and info flow to everyone; commands reach the bridge only from
the operator.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from bridge.bus.session import ZenohOptions
from tests.test_bus_session import free_endpoint, make_certificates

CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "tls"

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None,
                                reason="needs the openssl command")


def client_certificate(tmp: Path, name: str) -> None:
    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp, check=True, capture_output=True)
    run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-subj", f"/CN={name}", "-addext", "extendedKeyUsage=clientAuth",
        "-addext", f"subjectAltName=DNS:{name}", "-keyout", f"{name}.key", "-out", f"{name}.csr")
    run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "30", "-copy_extensions", "copy", "-out", f"{name}.pem")


def router_config(tmp: Path, endpoint: str) -> zenoh.Config:
    config = ZenohOptions(CONFIGS / "router-acl.json5").config()
    for key, name in (("listen_certificate", "router.pem"), ("listen_private_key", "router.key"),
                      ("root_ca_certificate", "ca.pem")):
        config.insert_json5(f"transport/link/tls/{key}", json.dumps(str(tmp / name)))
    config.insert_json5("listen/endpoints", json.dumps([endpoint]))
    return config


def client_config(tmp: Path, endpoint: str, name: str) -> zenoh.Config:
    config = ZenohOptions(CONFIGS / "client.json5").config()
    for key, value in (("root_ca_certificate", "ca.pem"), ("connect_certificate", f"{name}.pem"),
                       ("connect_private_key", f"{name}.key")):
        config.insert_json5(f"transport/link/tls/{key}", json.dumps(str(tmp / value)))
    config.insert_json5("transport/link/tls/enable_mtls", "true")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return config


def answers(session: zenoh.Session, key: str) -> list[str]:
    return [r.ok.payload.to_string() for r in session.get(key, timeout=2.0) if r.ok is not None]


def test_only_operators_reach_the_command_queryable(tmp_path: Path) -> None:
    make_certificates(tmp_path)
    for name in ("gx3-bridge", "gx3-recorder", "gx3-operator"):
        client_certificate(tmp_path, name)
    endpoint = free_endpoint().replace("tcp/127.0.0.1", "tls/localhost")
    got: list[bytes] = []
    with zenoh.open(router_config(tmp_path, endpoint)), \
            zenoh.open(client_config(tmp_path, endpoint, "gx3-bridge")) as bridge, \
            zenoh.open(client_config(tmp_path, endpoint, "gx3-recorder")) as recorder, \
            zenoh.open(client_config(tmp_path, endpoint, "gx3-operator")) as operator:
        info = bridge.declare_queryable("gx3/u1/info", lambda q: q.reply("gx3/u1/info", "id"))
        command = bridge.declare_queryable("gx3/u1/command",
                                           lambda q: q.reply("gx3/u1/command", "done"))
        sub = recorder.declare_subscriber("gx3/*/imu", lambda s: got.append(
            s.payload.to_bytes()))
        deadline = time.monotonic() + 10
        while not got and time.monotonic() < deadline:
            bridge.put("gx3/u1/imu", b"sample")
            time.sleep(0.1)
        assert got, "fleet data did not flow through the router"
        assert answers(recorder, "gx3/u1/info") == ["id"]
        assert answers(recorder, "gx3/u1/command") == [], "a non-operator sent a command"
        assert answers(operator, "gx3/u1/command") == ["done"]
        sub.undeclare()
        info.undeclare()
        command.undeclare()
