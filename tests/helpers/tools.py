"""Debian's daemons some tests run (chrony, linuxptp, Prometheus), unpacked, not installed."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest


def tool(name: str, package: str) -> str:
    """A daemon's path; without it the test is skipped, except where it must run: fails.

    .ci/run unpacks Debian's packages into the folder GX3_TOOLS names (installing and
    starting nothing); elsewhere the system's are used where they are installed. With
    GX3_TOOLS set (as .ci/run sets it, whether or not CI is) or in CI, a missing daemon
    fails the test: a check skipped there would pass without having run.

    Args:
        name: The program (chronyd, ptp4l, prometheus).
        package: Its Debian package, named in the skip.

    Returns:
        Its path.
    """
    tools = os.environ.get("GX3_TOOLS")
    unpacked = [str(Path(tools) / "usr" / sub) for sub in ("sbin", "bin")] if tools else []
    for where in [*unpacked, os.environ.get("PATH", ""), "/usr/sbin"]:
        found = shutil.which(name, path=where)
        if found:
            return found
    if tools or os.environ.get("CI"):
        pytest.fail(f"{name} is missing: .ci/run unpacks Debian's {package} into GX3_TOOLS"
                    + (f" ({tools} has none)" if tools else ""))
    pytest.skip(f"{name} is not installed (Debian's {package})")
