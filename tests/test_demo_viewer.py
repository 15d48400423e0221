"""`gx3 demo --viewer` where it cannot work: one line, before anything starts."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from tests.helpers.processes import GX3


def test_spawning_a_viewer_without_a_display_is_a_one_line_error(tmp_path: Path) -> None:
    assert GX3, "the gx3 console script is not installed next to this interpreter"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    output = tmp_path / "demo"
    done = subprocess.run([GX3, "demo", "--viewer", "spawn", "-o", str(output)], env=env,
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 2
    (line,) = done.stderr.splitlines()
    assert line.startswith("error: --viewer spawn: no display here")
    assert "--viewer serve" in line
    assert not output.exists(), "nothing should start"
