"""The demo recording in Rerun's real (headless) viewer: it loads, and every view shows.

Needs a Vulkan driver (Debian: mesa-vulkan-drivers); skipped without one.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bridge.fleet.snapshot import main, record_demo, render
from bridge.viz.demo import DEMO_EPOCH_NS, write_demo

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


def test_readme_picture_is_of_a_real_demo_run(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """The snapshot command pictures what gx3 demo recorded (bridges, Zenoh, recorder),
    with the cursor placed before the recording's end; a recording that is not there is
    one line and exit code 2."""
    rrd = record_demo(tmp_path / "demo", units=2, duration_s=3.0)
    png = tmp_path / "viewer.png"
    assert main([str(png), "--recording", str(rrd)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    state = render(rrd, tmp_path / "again.png", before_end_s=1.0, size=(800, 500))
    (recording,) = state.recordings
    (end,) = [t.end for t in recording.timelines if t.name == "time"]
    assert end is not None and recording.current_time == end - 10**9
    views = {(v.view_class, v.origin) for v in state.views}
    assert {("3D", "/world"), ("TimeSeries", "/plots/dropped")} <= views
    with pytest.raises(SystemExit) as exit_:
        main([str(png), "--recording", str(tmp_path / "none.rrd")])
    assert exit_.value.code == 2
    assert "none.rrd: no such file" in capsys.readouterr().err
