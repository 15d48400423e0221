"""The exit status rule, as scripts and service managers read it (docs/reference/cli.md).

A service (``bridge``, ``record``, ``view``, ``router``, ``sim``) runs until it is
stopped, so Ctrl-C or SIGTERM is how it ends: exit 0 (a bridge whose unit never came up
failed at its job: 1). Any other command stopped before its work was done exits 130 and
says it was interrupted. The bridge's, the recorder's and the demo's own cases are
tested beside their other behaviour (test_bridge_process, test_record_live, test_demo).
"""

from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest

from tests.helpers.processes import GX3, Sim, Stderr
from tests.helpers.waiting import free_port, wait_for


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stopped_service_exits_0(tmp_path: Path, sig: signal.Signals) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    sim = Sim(subprocess.Popen([GX3, "sim", "--pty"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE))
    router = subprocess.Popen([GX3, "router", "--listen", endpoint], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    view = subprocess.Popen([GX3, "view", "--connect", endpoint, "--save",
                             str(tmp_path / "view.rrd")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        sim.endpoints(1)
        assert router.stdout is not None and router.stdout.readline().strip() == b"READY"
        # the viewer's recording exists once it runs
        wait_for(lambda: (tmp_path / "view.rrd").exists())
    finally:
        codes = {}
        for name, proc in (("view", view), ("router", router), ("sim", sim.proc)):
            proc.send_signal(sig)
            _, stderr = proc.communicate(timeout=30)
            codes[name] = (proc.returncode, stderr.decode()[-300:])
    assert {name: code for name, (code, _) in codes.items()} == {
        "view": 0, "router": 0, "sim": 0}, codes


def test_an_interrupted_command_exits_130_and_says_so() -> None:
    """An operator command stopped while the unit samples: 130, one line, no traceback."""
    sim = Sim(subprocess.Popen([GX3, "sim", "--pty"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE))
    try:
        (port,) = sim.endpoints(1)
        proc = subprocess.Popen([GX3, "capture-bias", "--port", port, "--sampling-ms", "30000"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        stderr = Stderr(proc)
        wait_for(lambda: "sampling for" in stderr.read() or proc.poll() is not None)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 130, stderr.read()
        text = stderr.read()
        assert text.splitlines()[-1] == "error: interrupted", text
        assert "Traceback" not in text
    finally:
        sim.stop()
