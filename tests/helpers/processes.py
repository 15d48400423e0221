"""The installed ``gx3`` console script, and bridge, recorder and emulator processes run with it."""

from __future__ import annotations

import contextlib
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bridge.fleet.loopback import interrupt
from tests.helpers.waiting import wait_for


def _gx3() -> str:
    """The installed console script: next to this interpreter, else on PATH."""
    found = shutil.which("gx3", path=str(Path(sys.executable).parent)) or shutil.which("gx3")
    assert found, "the gx3 console script is not installed"
    return found


GX3 = _gx3()


def gx3(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """``gx3 ARGS`` run to the end: its exit code and text output (200 columns wide)."""
    assert GX3, "the gx3 console script is not installed next to this interpreter"
    return subprocess.run([GX3, *map(str, args)], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "COLUMNS": "200"})


@contextmanager
def bridge_process(port: str, cfg: Path, *args: str, env: dict[str, str] | None = None
                   ) -> Iterator[subprocess.Popen[bytes]]:
    """`gx3 bridge` on ``port`` with the Zenoh config ``cfg``; interrupted on leaving."""
    assert GX3, "the gx3 console script is not installed next to this interpreter"
    proc = subprocess.Popen([GX3, "bridge", "--port", port, "--zenoh-config", str(cfg),
                             *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=None if env is None else {**os.environ, **env})
    try:
        yield proc
    finally:
        interrupt([proc])
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()


def recorder(out: Path, cfg: Path, *args: str) -> subprocess.Popen[bytes]:
    """`gx3 record` into ``out`` with the Zenoh config ``cfg`` (the caller stops it).

    Where ``cfg`` listens, the recorder is returned once it does (or has exited): a
    bridge started before it would publish into the void, and only what its cache holds
    (half a second) would reach the archive, as in the field. On a busy machine the
    recorder's start can take seconds.
    """
    listen = re.search(r'"?listen"?\s*:\s*\{\s*"?endpoints"?\s*:\s*\[([^\]]*)\]',
                       cfg.read_text())  # JSON5: the tests' own configs and the shipped ones
    ports = [int(p) for p in re.findall(r"tcp/127\.0\.0\.1:(\d+)", listen[1] if listen else "")
             if p != "0"]  # :0, a port of the system's choosing, cannot be waited for
    proc = subprocess.Popen([GX3, "record", "-o", str(out), "--zenoh-config", str(cfg),
                             "--quiet", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for port in ports:
            wait_for(lambda: proc.poll() is not None or _accepts(port), 60,  # noqa: B023
                     f"the recorder to listen on port {port}")
    except BaseException:  # nobody else holds it yet: leave no recorder behind
        proc.kill()
        proc.communicate()
        raise
    return proc


def _accepts(port: int) -> bool:
    """Whether something listens on the loopback TCP ``port``."""
    with socket.socket() as probe:
        return probe.connect_ex(("127.0.0.1", port)) == 0


def published(stderr: bytes, unit: str) -> int:
    """The samples a bridge says it published, from its closing summary line."""
    found = re.search(rf"^{unit}: ([\d,]+) samples", stderr.decode(), re.M)
    assert found, stderr.decode()
    return int(found.group(1).replace(",", ""))


class Stderr:
    """What a child has written to its stderr pipe so far, read without blocking."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stderr is not None
        self.fd = proc.stderr.fileno()
        os.set_blocking(self.fd, False)
        self.text = ""

    def read(self) -> str:
        with contextlib.suppress(BlockingIOError):
            while chunk := os.read(self.fd, 1 << 16):
                self.text += chunk.decode()
        return self.text

    def waiting(self) -> list[str]:
        """The bridge's lines saying why the unit is not up."""
        return [line for line in self.read().splitlines() if " waiting " in line]


class Sim:
    """One running `gx3 sim` process."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        self.proc = proc

    def endpoints(self, n: int, timeout: float = 15.0) -> list[str]:
        """The first ``n`` lines of stdout, which name the endpoints."""
        assert self.proc.stdout is not None and self.proc.stderr is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        out = b""
        while out.count(b"\n") < n:
            left = deadline - time.monotonic()
            assert left > 0, f"gx3 sim printed only {out!r}"
            ready, _, _ = select.select([fd], [], [], left)
            if ready:
                chunk = os.read(fd, 4096)
                assert chunk, f"gx3 sim exited early: {self.proc.stderr.read().decode()}"
                out += chunk
        return out.decode().splitlines()[:n]

    def stop(self, sig: signal.Signals = signal.SIGTERM) -> tuple[int, str]:
        """Signal the process; its exit code and everything it wrote on stderr."""
        assert self.proc.stderr is not None
        self.proc.send_signal(sig)
        code = self.proc.wait(timeout=10)
        return code, self.proc.stderr.read().decode()
