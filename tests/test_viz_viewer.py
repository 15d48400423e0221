"""The demo recording in Rerun's real (headless) viewer: it loads, and every view shows.

Needs a Vulkan driver (Debian: mesa-vulkan-drivers); skipped without one.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.viz.demo import DEMO_EPOCH_NS, write_demo
from bridge.viz.snapshot import render

_ICDS = [p for d in ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d") if Path(d).is_dir()
         for p in Path(d).glob("*.json")]

pytestmark = pytest.mark.skipif(not _ICDS, reason="no Vulkan driver for the headless viewer "
                                "(apt-get install mesa-vulkan-drivers libvulkan1)")


def test_demo_recording_shows_in_the_viewer(tmp_path: Path) -> None:
    rrd, png = tmp_path / "demo.rrd", tmp_path / "shot.png"
    write_demo(rrd, seconds=5.0, gap_s=(2.0, 2.5))
    state = render(rrd, png, at_ns=DEMO_EPOCH_NS + 3 * 10**9, size=(1000, 700))
    (recording,) = state.recordings
    assert recording.store_id.endswith(":demo")
    assert {t.name for t in recording.timelines} >= {"time", "device_time"}
    assert recording.current_timeline == "time"
    assert recording.current_time == DEMO_EPOCH_NS + 3 * 10**9
    views = {(v.view_class, v.origin) for v in state.views}
    assert {("3D", "/world"), ("TextLog", "/events"), ("TimeSeries", "/plots/accel/x"),
            ("TimeSeries", "/plots/euler/roll"), ("TimeSeries", "/plots/clock_drift")} <= views
    assert [(v.name, r.summary) for v in state.views for r in v.reports] == []
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
