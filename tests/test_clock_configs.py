"""The clock configs under configs/clock run with the real daemons.

chrony: a time server on the server config and a bridge host on the bridge config, on
loopback, the bridge side measuring its offset from the server without touching this
host's clock (``-x`` on the server, ``-Q`` on the bridge side). linuxptp: ptp4l reads
the config to the end and only then finds that loopback has no hardware timestamps.

The daemons come from Debian's chrony and linuxptp packages: on PATH or /usr/sbin, or
unpacked where GX3_TOOLS points (.ci/run unpacks them there, installing nothing).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.helpers.tools import tool
from tests.helpers.waiting import free_port

CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "clock"


def local(config: str, tmp: Path, drop: tuple[str, ...], add: list[str],
          replace: tuple[str, str] | None = None) -> Path:
    """A shipped chrony config run on loopback from ``tmp``: directives that reach outside
    (upstream servers, system paths) left out, loopback ones added."""
    lines = []
    for line in (CONFIGS / config).read_text().splitlines():
        if line.split(" ", 1)[0] in drop:
            continue
        if replace is not None and line.startswith(replace[0]):
            line = replace[1] + line[len(replace[0]):]
        lines.append(line)
    name = tmp / config
    name.write_text("\n".join([*lines, *add,
                               f"pidfile {tmp / config}.pid", f"driftfile {tmp / config}.drift",
                               "cmdport 0"]) + "\n")
    return name


def test_a_bridge_host_follows_the_fleets_time_server(tmp_path: Path) -> None:
    chronyd = tool("chronyd", "chrony")
    port = free_port()
    server = local("chrony-server.conf", tmp_path, ("pool", "driftfile"),
                   [f"port {port}", "bindaddress 127.0.0.1", "allow 127.0.0.1"])
    bridge = local("chrony-bridge.conf", tmp_path, ("driftfile",), ["port 0"],
                   ("server router.local", f"server 127.0.0.1 port {port}"))
    serving = subprocess.Popen([chronyd, "-x", "-d", "-u", "root", "-f", str(server)],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        measured = subprocess.run([chronyd, "-Q", "-u", "root", "-f", str(bridge)],
                                  capture_output=True, text=True, timeout=60, check=False)
    finally:
        serving.terminate()
        said = serving.communicate(timeout=30)[0].decode()
    assert "Invalid" not in said and "Could not" not in said, said
    assert measured.returncode == 0, measured.stderr
    assert "System clock wrong by" in measured.stderr + measured.stdout, measured.stderr


def test_ptp4l_takes_the_whole_config(tmp_path: Path) -> None:
    ptp4l = tool("ptp4l", "linuxptp")
    bad = tmp_path / "bad.conf"
    bad.write_text("[global]\nno_such_option 1\n")
    for config, parsed in ((CONFIGS / "ptp4l.conf", True), (bad, False)):
        done = subprocess.run([ptp4l, "-f", str(config), "-i", "lo", "-m"],
                              capture_output=True, text=True, timeout=30, check=False)
        said = done.stdout + done.stderr
        assert ("failed to parse configuration file" not in said) == parsed, said
        if parsed:  # it went on to the interface, which has no hardware timestamps
            assert "timestamping" in said, said
