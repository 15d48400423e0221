"""`gx3 calibrate-mag` end to end: a 90 s tumbling capture of an emulated unit among known
iron, with noise, replayed into an archive; the calibration file is checked against truth."""

from __future__ import annotations

import json
import signal
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from rerun.chunk import RrdReader

from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.walk import read_archive
from bridge.ingest.replay import replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import Motion, MotionConfig, tumbling
from bridge.sim.serve import Simulator
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from tests.helpers.cli import gx3_here
from tests.helpers.processes import GX3, bridge_process
from tests.helpers.rrd import blueprint_views, plot_values, rerun_rows_so_far
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config

SOFT = (1.1, 0.05, 0.0, 0.05, 0.9, -0.02, 0.0, -0.02, 1.0)
HARD = (0.12, -0.3, 0.05)
EARTH = (0.2, 0.0, 0.45)
FIELD = float(np.linalg.norm(EARTH))


def captured(folder: Path, unit: str, motion: MotionConfig, seconds: float) -> Path:
    cap = synthesize(streaming_config(UnitConfig(motion=motion), code=0xCC, decimation=10),
                     UsbDelivery(seed=1), seconds=seconds)
    meta = {"unit": unit, "record": "0xcc", "decimation": "10", "filter_width": "15",
            "baud": "115200", "transport": "usb"}
    path = folder / f"{unit}.raw.mcap"
    writer = RawCaptureWriter(path, "gx3", unit, meta)
    for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
        writer.write(data, rx)
    writer.close()
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """imu0 tumbles for 90 s among iron, with magnetometer noise; flat only turns about z.
    No linear acceleration: the accelerometer shows which way is down, for the heading."""
    folder = tmp_path_factory.mktemp("magcal")
    iron = MotionConfig(seed=4, hard_iron_gauss=HARD, soft_iron=SOFT, earth_field_gauss=EARTH,
                        noise_mag_gauss=0.003, linear_accel_amplitude_g=0.0)
    tumbler = captured(folder, "imu0", tumbling(iron), 90.0)
    flat = captured(folder, "flat", replace(iron, attitude_amplitude_rad=0.0,
                                            spin_rad_s=(0.0, 0.5)), 20.0)
    replay([tumbler, flat], folder / "iron.mcap")
    return folder / "iron.mcap"


def test_the_calibration_of_a_tumbling_unit_is_the_true_iron(recording: Path,
                                                              tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    done = gx3_here("calibrate-mag", recording, "--unit", "imu0", "-o", out)
    assert done.exit_code == 0, done.stderr
    assert "wrote" in done.stderr and "warning" not in done.stderr
    cal = json.loads(out.read_text())
    hard, soft = np.array(cal["hard_iron"]), np.array(cal["soft_iron"])
    assert np.linalg.norm(hard - HARD) < 0.01 * FIELD
    np.testing.assert_allclose(soft, soft.T, atol=1e-6)
    # The true field, every way round, through the emulator's iron and this calibration.
    truth = Motion(MotionConfig(seed=1)).magnetometer(np.arange(0, 90, 0.05))
    truth = truth / np.linalg.norm(truth, axis=1, keepdims=True) * FIELD
    corrected = (truth @ np.reshape(SOFT, (3, 3)).T + HARD - hard) @ soft.T
    size = np.linalg.norm(corrected, axis=1)
    assert np.abs(size / size.mean() - 1).max() < 0.005
    assert cal["unit"] == "imu0" and cal["quantity"] == "mag"
    assert cal["model"] == "corrected = soft_iron @ (raw - hard_iron)"
    assert cal["coverage"] == 1.0 and cal["readings"] > 8900
    assert cal["residual_after"] < 0.01 < 0.1 < cal["residual_before"]
    assert 89.0 < cal["span"]["seconds"] < 90.1 and cal["span"]["start_utc"].endswith("Z")
    assert cal["field_gauss"] == pytest.approx(FIELD, rel=0.05)


def test_a_span_and_a_refused_output(recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    done = gx3_here("calibrate-mag", recording, "-u", "imu0", "-o", out, "--start", "10",
               "--end", "40")
    assert done.exit_code == 0, done.stderr
    assert 29.9 < json.loads(out.read_text())["span"]["seconds"] < 30.0
    again = gx3_here("calibrate-mag", recording, "-u", "imu0", "-o", out)
    assert again.exit_code == 2 and again.stderr.count("\n") == 1, again.stderr
    assert gx3_here("calibrate-mag", recording, "-u", "imu0", "-o", out, "--force").exit_code == 0


def test_a_flat_turn_is_refused_naming_the_missing_motion(recording: Path,
                                                          tmp_path: Path) -> None:
    out = tmp_path / "cal.json"
    done = gx3_here("calibrate-mag", recording, "--unit", "flat", "-o", out)
    assert done.exit_code == 2
    assert done.stderr.count("\n") == 1, done.stderr
    assert "span a plane" in done.stderr and "its z axis" in done.stderr
    assert "turn it also about its x and y axes" in done.stderr
    assert not out.exists()


@pytest.mark.parametrize(("args", "message"), [
    (("--unit", "nobody"), "has no unit 'nobody'"),
    ((), "holds 2 units"),
    (("--unit", "imu0", "--start", "soon"), "'soon' is neither"),
    (("--unit", "imu0", "--start", "200"), "no samples of unit imu0 from --start to --end"),
])
def test_bad_input_is_one_line(recording: Path, tmp_path: Path, args: tuple[str, ...],
                               message: str) -> None:
    done = gx3_here("calibrate-mag", recording, "-o", tmp_path / "cal.json", *args)
    assert done.exit_code == 2
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    assert not (tmp_path / "cal.json").exists()


@pytest.fixture(scope="module")
def calibration(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cal") / "imu0.json"
    assert gx3_here("calibrate-mag", recording, "-u", "imu0", "-o", out).exit_code == 0
    return out


def test_export_applies_the_calibration_and_adds_a_compass_heading(
        recording: Path, calibration: Path, tmp_path: Path) -> None:
    plain, ironed = tmp_path / "plain.parquet", tmp_path / "ironed.parquet"
    assert gx3_here("export", recording, "-o", plain).exit_code == 0
    done = gx3_here("export", recording, "-o", ironed, "--mag-cal", calibration)
    assert done.exit_code == 0, done.stderr
    before, after = pq.read_table(plain).to_pydict(), pq.read_table(ironed)
    table = after.to_pydict()
    names = after.column_names
    assert names[names.index("mag_z") + 1] == "mag_heading"
    imu0 = np.array(table["unit"]) == "imu0"
    mag = np.column_stack([np.array(table[f"mag_{a}"]) for a in "xyz"])
    raw = np.column_stack([np.array(before[f"mag_{a}"]) for a in "xyz"])
    size = np.linalg.norm(mag[imu0], axis=1)
    assert np.sqrt(np.mean((size / size.mean() - 1) ** 2)) < 0.005
    assert size.mean() == pytest.approx(FIELD, rel=0.05)
    np.testing.assert_array_equal(mag[~imu0], raw[~imu0])  # flat has no calibration
    # The compass heading is the true yaw of the unit's M (body x: M's first row).
    heading = np.array(table["mag_heading"], dtype=float)
    yaw = np.arctan2(np.array(table["m12"]), np.array(table["m11"]))
    error = np.angle(np.exp(1j * (heading[imu0] - yaw[imu0])))
    assert np.abs(error).max() < np.radians(2.0)
    assert np.isnan(heading[~imu0]).all()
    meta = after.schema.metadata
    assert json.loads(meta[b"gx3.mag_cal"])["imu0"] == json.loads(calibration.read_text())
    field = after.schema.field("mag_heading").metadata
    assert field[b"physical_unit"] == b"rad"


def test_an_aligned_export_has_the_heading_of_the_calibrated_unit(
        recording: Path, calibration: Path, tmp_path: Path) -> None:
    out = tmp_path / "aligned.parquet"
    done = gx3_here("export", recording, "-o", out, "--mag-cal", calibration, "--align", "50")
    assert done.exit_code == 0, done.stderr
    names = pq.read_schema(out).names
    assert "imu0__mag_heading" in names and "flat__mag_heading" not in names


@pytest.mark.parametrize(("text", "message"), [
    ("{", "not JSON"),
    ('{"unit": "imu0", "hard_iron": [0, 0], "soft_iron": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}',
     "not a calibration"),
    ('{"unit": "imu9", "hard_iron": [0, 0, 0], "soft_iron": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}',
     "the calibration of unit imu9 has no samples"),
])
def test_a_bad_calibration_file_is_one_line(recording: Path, tmp_path: Path, text: str,
                                            message: str) -> None:
    cal = tmp_path / "cal.json"
    cal.write_text(text)
    done = gx3_here("export", recording, "-o", tmp_path / "out.parquet", "--mag-cal", cal)
    assert done.exit_code == 2
    assert done.stderr.count("\n") == 1 and message in done.stderr, done.stderr
    assert not (tmp_path / "out.parquet").exists()


def test_the_fit_drawn_in_rerun_as_the_manuals_figure_3(recording: Path, tmp_path: Path) -> None:
    out, drawing = tmp_path / "cal.json", tmp_path / "fit.rrd"
    done = gx3_here("calibrate-mag", recording, "-u", "imu0", "-o", out, "--rrd", drawing)
    assert done.exit_code == 0, done.stderr
    cal = json.loads(out.read_text())
    store = RrdReader(drawing).stream().collect()

    def column(entity: str, name: str) -> np.ndarray:
        found = store.reader(index=None, contents=entity).to_arrow_table()
        return np.array(found.column(f"{entity}:{name}").to_pylist()[0])

    raw = column("/raw/readings", "Points3D:positions")
    corrected = column("/corrected/readings", "Points3D:positions")
    assert len(raw) == len(corrected) > 4000
    np.testing.assert_allclose(np.linalg.norm(corrected, axis=1), cal["field_gauss"], rtol=0.02)
    np.testing.assert_allclose(column("/raw/ellipsoid", "Ellipsoids3D:centers")[0],
                               cal["hard_iron"], rtol=1e-5)
    half = column("/raw/ellipsoid", "Ellipsoids3D:half_sizes")[0]
    assert sorted(half) == pytest.approx(sorted(cal["field_gauss"] / np.linalg.eigvalsh(
        np.array(cal["soft_iron"]))), rel=1e-5)
    # The raw readings lie on the ellipsoid as drawn (its rotation a Hamilton xyzw quaternion).
    x, y, z, w = column("/raw/ellipsoid", "Ellipsoids3D:quaternions")[0]
    turn = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    local = (raw - cal["hard_iron"]) @ turn / half
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), 1.0, rtol=0.02)
    views = blueprint_views(drawing)[0]
    assert {("3D", "/raw"), ("3D", "/corrected"), ("TextDocument", "/calibration")} <= views


def plotted_mag(rrd: Path, unit: str) -> np.ndarray:
    """The mag a Rerun file plots for ``unit`` as (N, 3) rows."""
    return plot_values(RrdReader(rrd).stream().collect(), "mag", unit)


def test_rrd_shows_the_calibrated_units_mag_corrected(recording: Path, calibration: Path,
                                                      tmp_path: Path) -> None:
    out = tmp_path / "ironed.rrd"
    done = gx3_here("rrd", recording, "-o", out, "--mag-cal", calibration)
    assert done.exit_code == 0, done.stderr
    size = np.linalg.norm(plotted_mag(out, "imu0"), axis=1)
    assert len(size) > 8900
    assert np.sqrt(np.mean((size / size.mean() - 1) ** 2)) < 0.005
    raw = np.concatenate([b.columns["mag"] for b in read_archive(recording).samples(["flat"])])
    np.testing.assert_array_equal(plotted_mag(out, "flat"), raw)  # no calibration: as recorded


def test_rrd_refuses_a_calibration_of_a_unit_it_lacks(recording: Path, tmp_path: Path) -> None:
    cal = tmp_path / "cal.json"
    cal.write_text('{"unit": "imu9", "hard_iron": [0, 0, 0], '
                   '"soft_iron": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}')
    done = gx3_here("rrd", recording, "-o", tmp_path / "out.rrd", "--mag-cal", cal)
    assert done.exit_code == 2
    assert done.stderr.count("\n") == 1 and "unit imu9 has no samples" in done.stderr
    assert not (tmp_path / "out.rrd").exists()


def test_view_shows_a_live_units_mag_corrected(tmp_path: Path) -> None:
    """A live bridge's unit a through gx3 view --mag-cal: a calibration far from the truth
    (hard iron (1, 2, 3), soft 2 I) shows as 2 (raw - hard), whose raw is the field."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    view_cfg = zenoh_config(tmp_path / "view.json5", listen=[endpoint])
    bridge_cfg = zenoh_config(tmp_path / "bridge.json5", connect=[endpoint])
    cal, rrd = tmp_path / "a.json", tmp_path / "live.rrd"
    cal.write_text('{"unit": "a", "hard_iron": [1, 2, 3], '
                   '"soft_iron": [[2, 0, 0], [0, 2, 0], [0, 0, 2]]}')
    viewer = subprocess.Popen([GX3, "view", "--save", str(rrd), "--zenoh-config",
                               str(view_cfg), "--mag-cal", str(cal)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        with Simulator(TWO_UNITS[:1], "pty") as sim, \
                bridge_process(sim.endpoints[0], bridge_cfg, "--unit", "a"):
            wait_for(lambda: rerun_rows_so_far(rrd, "/plots/mag/z/a") >= 100)
        viewer.send_signal(signal.SIGINT)
        _, stderr = viewer.communicate(timeout=30)
    finally:  # a failed wait leaves no viewer behind
        if viewer.poll() is None:
            viewer.kill()
            viewer.communicate()
    assert viewer.returncode == 0, stderr.decode()
    mag = plotted_mag(rrd, "a")
    assert len(mag) >= 100
    raw = mag / 2 + [1, 2, 3]
    np.testing.assert_allclose(np.linalg.norm(raw, axis=1), FIELD, rtol=0.02)
