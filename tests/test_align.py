"""`gx3 align` on four emulated units fixed to one body turned by hand for 3 minutes at
500 Hz: one upside down and turned 90°, one turned ~177° with a few degrees of error, lever
arms up to 0.5 m, one behind a constant 3.2 ms link, on their own clocks, links and
filters, with noise and biases. Each unit's mounting is found as the emulator made it and
its time shift as the archive really needs it (the emulator knows each record's true
instant); `gx3 export --mounts` then puts every unit in the reference's axes and time."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag1 import Reader
from rosbags.typesys import Stores, get_typestore

from bridge.analysis.align import MAX_GRID_HZ
from bridge.analysis.mounts import Mounts, read_mounts
from bridge.protocol.convert import quaternion_to_m
from bridge.sim.usb import AdapterDelivery, UsbDelivery
from tests.helpers.body import Body, BodyUnit, body_archive
from tests.helpers.cli import gx3_here
from tests.helpers.rotations import rotation

SECONDS = 180.0
REF = "imu1"
#: imu1 and flip are on identical links (the unit's own USB port, the same filter), so
#: flip's time shift checks the fleet's own timing; turn streams 0xCC (with M) through an
#: adapter with the widest filter, late the narrowest behind a 3.2 ms link.
UNITS = [
    BodyUnit(REF, ppm=12.0, delivery=UsbDelivery(seed=1, frame_phase_s=0.00031)),
    BodyUnit("flip", (180.0, 0.0, 90.0), (0.5, 0.0, 0.0), ppm=-40.0,
             delivery=UsbDelivery(seed=2, frame_phase_s=0.00077)),
    BodyUnit("turn", (2.3, -1.7, 177.4), (-0.2, 0.35, 0.1), ppm=3.0, filter_width=32,
             delivery=AdapterDelivery(seed=3, latency_timer_s=0.001), baud=921600,
             code=0xCC),
    BodyUnit("late", (0.0, 90.0, 0.0), (0.1, -0.3, -0.25), ppm=75.0, filter_width=1,
             link_latency_s=0.0032, delivery=UsbDelivery(seed=4, frame_phase_s=0.00052)),
]
OTHERS = [u.name for u in UNITS[1:]]
NOETIC = get_typestore(Stores.ROS1_NOETIC)


@dataclass
class Aligned:
    body: Body
    table: dict[str, np.ndarray]  # the archive's samples as gx3 export times them
    mounts: Mounts
    path: Path
    stderr: str


@pytest.fixture(scope="module")
def aligned(tmp_path_factory: pytest.TempPathFactory) -> Aligned:
    folder = tmp_path_factory.mktemp("align")
    body = body_archive(folder, UNITS, SECONDS)
    out = folder / "mounts.yaml"
    done = gx3_here("align", body.path, *(a for u in UNITS for a in ("-u", u.name)), "-o", out)
    assert done.exit_code == 0, done.stderr
    return Aligned(body, body.read()[1], read_mounts(out), out, done.stderr)


def _angle_deg(r: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))))


@pytest.mark.parametrize("unit", OTHERS)
def test_each_unit_is_found_as_it_is_mounted_and_timed(aligned: Aligned, unit: str) -> None:
    mount, body = aligned.mounts.units[unit], aligned.body
    assert _angle_deg(mount.rotation @ body.rotation(REF, unit).T) < 0.1
    np.testing.assert_allclose(rotation(mount.quaternion_xyzw), mount.rotation, atol=1e-8)
    needed = body.needed_shift(aligned.table, REF, unit)
    assert abs(mount.time_shift_s - needed) < 1e-4
    assert mount.lever_arm_m is not None
    assert np.abs(mount.lever_arm_m - body.lever_arm(REF, unit)).max() < 0.02


def test_the_link_that_no_clock_model_sees_is_measured(aligned: Aligned) -> None:
    """late's bytes come 3.2 ms later: its times are late by that, and the shift undoes it."""
    assert aligned.mounts.units["late"].time_shift_s == pytest.approx(-0.0032, abs=2e-4)


def test_two_units_on_identical_links_need_a_shift_of_about_zero(aligned: Aligned) -> None:
    """The fleet's own timing check (docs/guides/time.md): imu1 and flip differ only in
    their clocks, mountings and motion, so the measured shift is an independent
    measurement of how well the archive times them."""
    shift = aligned.mounts.units["flip"].time_shift_s
    assert abs(shift) < 2e-5
    assert abs(shift - aligned.body.needed_shift(aligned.table, REF, "flip")) < 1e-5


def test_the_file_says_how_sure_it_is_and_what_it_used(aligned: Aligned) -> None:
    text = aligned.path.read_text()
    assert text.startswith("# How each unit is mounted against the reference")
    assert f"reference: {REF}\nunits:\n  flip:\n    rotation: [[" in text
    from ruamel.yaml import YAML

    content = YAML(typ="safe", pure=True).load(text)
    for unit in OTHERS:
        entry = content["units"][unit]
        for key in ("rotation_sigma_deg", "time_shift_sigma_s", "lever_arm_sigma_m",
                    "rate_residual_rad_s", "force_residual_m_s2"):
            assert all(isinstance(v, float) and v > 0 for v in np.ravel(entry[key])), key
        assert max(entry["rotation_sigma_deg"]) < 0.01
        assert entry["time_shift_sigma_s"] < 2e-5
        assert max(entry["lever_arm_sigma_m"]) < 0.002
        assert entry["span"]["seconds"] > SECONDS - 1
        assert entry["span"]["samples"] > 0.99 * SECONDS * MAX_GRID_HZ  # instants used
        span = entry["span"]  # YAML reads the instants as timestamps
        assert (span["end_utc"] - span["start_utc"]).total_seconds() == pytest.approx(
            span["seconds"], abs=2e-3)
    assert content["source"] == "body.mcap"
    assert "wrote" in aligned.stderr and "3 units against imu1" in aligned.stderr
    assert "late: turned 90.00°" in aligned.stderr


@pytest.fixture(scope="module")
def exported(aligned: Aligned, tmp_path_factory: pytest.TempPathFactory
             ) -> dict[str, np.ndarray]:
    out = tmp_path_factory.mktemp("mounted") / "mounted.parquet"
    done = gx3_here("export", aligned.body.path, "-o", out, "--mounts", aligned.path,
               "--start", "60", "--end", "80")
    assert done.exit_code == 0, done.stderr
    table = pq.read_table(out)
    meta = json.loads(table.schema.metadata[b"gx3.mounts"])
    assert meta["file"] == "mounts.yaml" and meta["reference"] == REF
    assert meta["sha256"] == hashlib.sha256(aligned.path.read_bytes()).hexdigest()
    assert sorted(meta["units"]) == sorted(OTHERS)
    return {k: np.asarray(v) for k, v in table.to_pydict().items()}


def _column(table: dict[str, np.ndarray], rows: np.ndarray, name: str) -> np.ndarray:
    return np.column_stack([table[f"{name}_{a}"][rows] for a in "xyz"]).astype(float)


@pytest.mark.parametrize("unit", OTHERS)
def test_export_puts_each_unit_on_the_references_time_and_axes(
        aligned: Aligned, exported: dict[str, np.ndarray], unit: str) -> None:
    """Against the truth: a mounted unit's exported instants are off their true instants
    as the reference's are (the reference's time), and its rates, turned into the
    reference's axes, are the reference's at those instants."""
    body = aligned.body
    _, ref_error = body.errors(exported, REF)
    _, error = body.errors(exported, unit)
    assert abs(np.mean(error) - np.mean(ref_error)) < 1e-4 * 1e9
    ref_rows, rows = exported["unit"] == REF, exported["unit"] == unit
    t = exported["time_ns"]
    assert t[rows].min() >= t.min() and np.all(np.diff(t) >= 0)
    mine = _column(exported, rows, "ang_rate")
    theirs = np.column_stack([np.interp(t[rows], t[ref_rows], c)
                              for c in _column(exported, ref_rows, "ang_rate").T])
    # noise and gyro biases differ: nothing of the motion (rates of rad/s) is left
    left = np.sqrt(np.mean(np.sum((mine - theirs) ** 2, axis=1)))
    assert left < 0.03
    assert np.sqrt(np.mean(np.sum(theirs ** 2, axis=1))) > 30 * left


def test_export_turns_the_attitude_into_the_references(
        aligned: Aligned, exported: dict[str, np.ndarray]) -> None:
    """turn streams M: exported, it is the reference's axes' true attitude."""
    rows = np.flatnonzero(exported["unit"] == "turn")
    m = np.stack([exported[f"m{r}{c}"][rows] for r in "123" for c in "123"], axis=1)
    truth = aligned.body.truth["turn"]
    at = np.searchsorted(truth["timer"], exported["timer"][rows])
    own = quaternion_to_m(truth["quaternion"][at])
    expected = aligned.body.rotation(REF, "turn").T @ own
    worst = max(_angle_deg(a @ b.T) for a, b in zip(
        m.reshape(-1, 3, 3).astype(float), expected, strict=True))
    assert worst < 0.1


def test_a_bag_with_mounts_is_in_the_references_frame(aligned: Aligned,
                                                      tmp_path: Path) -> None:
    """ROS 2 and ROS 1 alike: every unit's Imu messages in the reference's frame, and the
    mounts file recorded (a metadata record; a latched String on /gx3/gx3_mounts)."""
    for out in (tmp_path / "mounted.ros2.mcap", tmp_path / "mounted.bag"):
        done = gx3_here("export", aligned.body.path, "-o", out, "--mounts", aligned.path,
                        "--start", "10", "--end", "11")
        assert done.exit_code == 0, done.stderr
    frames: dict[str, set[str]] = {}
    with (tmp_path / "mounted.ros2.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        records = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        for _, channel, _, decoded in reader.iter_decoded_messages():
            frames.setdefault(channel.topic, set()).add(decoded.header.frame_id)
    expected = {f"/gx3/{u.name}/imu": {f"gx3_{REF}"} for u in UNITS}
    assert {topic: names for topic, names in frames.items() if "imu" in topic} == expected
    record = records["gx3.mounts"]
    assert record["sha256"] == hashlib.sha256(aligned.path.read_bytes()).hexdigest()
    assert json.loads(record["units"])["late"]["time_shift_s"] == pytest.approx(-0.0032,
                                                                                abs=2e-4)
    ros1: dict[str, set[str]] = {}
    latched: list[Any] = []
    with Reader(tmp_path / "mounted.bag") as bag:
        for connection, _, data in bag.messages():
            message: Any = NOETIC.deserialize_ros1(data, connection.msgtype)
            if connection.topic == "/gx3/gx3_mounts":
                latched.append(json.loads(message.data))
            else:
                ros1.setdefault(connection.topic, set()).add(message.header.frame_id)
    assert {topic: names for topic, names in ros1.items() if "imu" in topic} == expected
    assert len(latched) == 1 and latched[0]["sha256"] == record["sha256"]
    assert latched[0]["units"] == json.loads(record["units"])


def test_export_refuses_mounts_into_a_csv_file(aligned: Aligned, tmp_path: Path) -> None:
    done = gx3_here("export", aligned.body.path, "--mounts", aligned.path, "-o",
               tmp_path / "out.csv")
    assert done.exit_code == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "a CSV file has none (write .parquet" in done.stderr
    assert not list(tmp_path.iterdir())
