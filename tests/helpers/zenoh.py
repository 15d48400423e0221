"""Zenoh on loopback: peer configs with scouting off, connected sessions, TLS certificates."""

from __future__ import annotations

import subprocess
from pathlib import Path

import zenoh

from bridge.bus.session import open_session
from bridge.fleet.loopback import free_port, loopback_config


def zenoh_config(path: Path, listen: list[str] | None = None,
                 connect: list[str] | None = None) -> Path:
    """A peer on loopback with multicast scouting off, as every test session is."""
    return loopback_config(path, listen or [], connect or [])


def peer_sessions(n: int) -> list[zenoh.Session]:
    """A listening session and ``n`` - 1 connected to it, on loopback (the caller closes
    them)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    return [open_session(listen=[endpoint], mode="peer", multicast_scouting=False)] + [
        open_session(connect=[endpoint], mode="peer", multicast_scouting=False)
        for _ in range(n - 1)]


def make_certificates(tmp: Path) -> None:
    """A CA, another CA, and a router certificate for localhost: the commands of
    configs/tls/router.json5."""
    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp, check=True, capture_output=True)
    for ca in ("ca", "other-ca"):
        run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
            "-days", "30", "-subj", f"/CN={ca}", "-keyout", f"{ca}.key", "-out", f"{ca}.pem")
    run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost",
        "-keyout", "router.key", "-out", "router.csr")
    run("x509", "-req", "-in", "router.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
        "-CAcreateserial", "-days", "30", "-copy_extensions", "copy", "-out", "router.pem")
