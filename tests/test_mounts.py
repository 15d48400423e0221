"""The mounts file (what `gx3 align` writes, and what another tool may write) read back,
what applying it does to every quantity a record holds, and `gx3 rrd --mounts` drawing a
unit behind a 3.2 ms link in the reference's axes and time."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from bridge.analysis.mounts import TURNS, Mount, MountFit, Mounts, mounts_yaml, read_mounts
from bridge.archive.writer import ArchiveWriter
from bridge.exceptions import MountsFileError
from bridge.protocol import convert
from bridge.sim.archived import archive_samples
from bridge.sim.motion import Motion, MotionConfig, Mounting, handheld
from bridge.viz import layout
from tests.helpers.processes import gx3
from tests.helpers.rotations import rotation
from tests.helpers.rrd import plot_values, table

TURNED = Mounting.turned((2.3, -1.7, 177.4))
FIT = MountFit(np.array([1e-3, 2e-3, 3e-3]), 4e-6, np.array([1e-4, 2e-4, 3e-4]), "",
               0.01, 0.03, (1_763_000_000_000_000_000, 1_763_000_060_000_000_000), 29_000)


def test_what_align_writes_reads_back(tmp_path: Path) -> None:
    mounts = Mounts("imu-1", {
        "2nd": Mount("2nd", TURNED.matrix, -0.0032, np.array([0.3, -0.05, 0.25]), FIT),
        "yes": Mount("yes", np.eye(3), 0.0, None, MountFit(
            FIT.rotation_sigma_deg, 1e-6, None, "not observable: along x", 0.01, None,
            FIT.span_ns, 100))}, "fleet.mcap")
    path = tmp_path / "mounts.yaml"
    path.write_text(mounts_yaml(mounts))
    back = read_mounts(path)
    assert back.reference == "imu-1" and list(back.units) == ["2nd", "yes"]
    assert back.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    np.testing.assert_allclose(back.units["2nd"].rotation, TURNED.matrix, atol=1e-9)
    assert back.units["2nd"].time_shift_s == -0.0032
    arm = back.units["2nd"].lever_arm_m
    assert arm is not None
    np.testing.assert_allclose(arm, np.array([0.3, -0.05, 0.25]))
    assert back.units["yes"].lever_arm_m is None and back.source == "fleet.mcap"
    text = path.read_text()
    assert '\n  "2nd":\n' in text and '\n  "yes":\n' in text  # YAML would read 2nd, yes
    assert 'lever_arm_note: "not observable: along x"' in text
    assert "time_shift_sigma_s: 4.00e-06" in text


def test_a_file_with_a_quaternion_alone_is_read(tmp_path: Path) -> None:
    """Another tool's file: the rotation as a Hamilton quaternion, x y z w."""
    xyzw = np.array([0.1, -0.2, 0.3, 0.9])
    xyzw /= np.linalg.norm(xyzw)
    path = tmp_path / "cad.yaml"
    path.write_text(f"reference: a\nunits:\n  b:\n    quaternion_xyzw: {xyzw.tolist()}\n")
    mount = read_mounts(path).units["b"]
    np.testing.assert_allclose(mount.rotation, rotation(xyzw), atol=1e-12)
    np.testing.assert_allclose(mount.quaternion_xyzw, xyzw, atol=1e-12)
    assert mount.time_shift_s == 0.0 and mount.lever_arm_m is None


@pytest.mark.parametrize(("text", "message"), [
    ("reference: a\n", "not a mounts file (it needs reference: UNIT and units:"),
    ("reference: a\nunits:\n  b:\n    rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 2]]\n",
     "b: rotation is not a rotation (its rows must be orthonormal"),
    ("reference: a\nunits:\n  b:\n    rotation: [[1, 0, 0], [0, 1, 0], [0, 0, -1]]\n",
     "b: rotation is not a rotation"),
    ("reference: a\nunits:\n  b:\n    rotation: [1, 0, 0]\n", "b: rotation is not 3 x 3"),
    ("reference: a\nunits:\n  b:\n    time_shift_s: 0.1\n",
     "b: neither rotation nor quaternion_xyzw is given"),
    ("reference: a\nunits:\n  b:\n    quaternion_xyzw: [0, 0, 0, 2]\n",
     "b: quaternion_xyzw is not of length 1"),
    ("reference: a\nunits:\n  b:\n    quaternion_xyzw: [0, 0, 1, 0]\n"
     "    rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n",
     "b: rotation and quaternion_xyzw are not the same rotation"),
    ("reference: a\nunits:\n  b:\n    rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n"
     "    time_shift_s: soon\n", "b: time_shift_s is 'soon', not a number of seconds"),
    ("reference: a\nunits:\n  a:\n    rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n",
     "the reference a is among its own units"),
    ("reference: [a\n", "not YAML"),
])
def test_a_file_that_cannot_be_used_is_one_line_saying_why(tmp_path: Path, text: str,
                                                           message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(MountsFileError) as caught:
        read_mounts(path)
    assert message in str(caught.value) and "\n" not in str(caught.value)
    assert str(caught.value).endswith("give the mounts.yaml that gx3 align wrote")


def test_every_quantity_is_put_in_the_references_axes() -> None:
    """Vectors as rotation^T v; M, its quaternion and Euler angles as the reference axes'
    attitude (rotation^T M); C at both ends; raw codes as they are; NaN rows stay NaN."""
    r = TURNED.matrix
    mount = Mount("u", r)
    rng = np.random.default_rng(1)
    euler = np.stack([rng.uniform(-3, 3, 5), rng.uniform(-1.2, 1.2, 5),
                      rng.uniform(-3, 3, 5)], axis=1)
    m = convert.euler_to_m(euler)
    c = convert.euler_to_m(euler * 1e-3)
    vectors = rng.normal(size=(5, 3)).astype(np.float32)
    vectors[2] = np.nan
    names = ("accel", "ang_rate", "mag", "stab_accel", "stab_mag", "delta_ang", "delta_vel")
    columns: dict[str, np.ndarray] = {
        **dict.fromkeys(names, vectors), "m": m, "quaternion": convert.m_to_quaternion(m),
        "euler": euler, "c": c, "raw_accel": vectors, "time_ns": np.arange(5)}
    out = mount.express(columns)
    assert set(TURNS) < set(columns)
    for name in names:
        assert out[name].dtype == np.float32
        np.testing.assert_allclose(out[name], (r.T @ vectors.T).T, atol=1e-6)
        assert np.isnan(out[name][2]).all()
    expected = r.T @ m
    np.testing.assert_allclose(out["m"], expected, atol=1e-12)
    np.testing.assert_allclose(convert.quaternion_to_m(out["quaternion"]), expected, atol=1e-12)
    np.testing.assert_allclose(convert.euler_to_m(out["euler"]), expected, atol=1e-12)
    np.testing.assert_allclose(out["c"], r.T @ c @ r, atol=1e-12)
    flat = mount.express({"m": m.reshape(5, 9).astype(np.float32)})["m"]
    np.testing.assert_allclose(flat.reshape(5, 3, 3), expected, atol=1e-6)
    assert out["raw_accel"] is vectors and out["time_ns"] is columns["time_ns"]


@pytest.fixture(scope="module")
def late(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two units on one body for 20 s at 100 Hz: u2 turned and 0.3 m away, its samples
    archived 3.2 ms late; and the mounts file that says so."""
    folder = tmp_path_factory.mktemp("late")
    mounted = Mounting.turned((180.0, 0.0, 90.0), (0.3, 0.0, 0.0), 3)
    with ArchiveWriter(folder / "late.mcap") as writer:
        for unit, mounting, delay_ns in (("u1", Mounting(3), 0), ("u2", mounted, 3_200_000)):
            motion = Motion(handheld(MotionConfig(seed=1), mounting))
            archive_samples(writer, unit, motion, np.arange(0.0, 20.0, 0.01), 0.01,
                            wall_ns=1_763_000_000_000_000_000 + delay_ns)
    path = folder / "mounts.yaml"
    path.write_text(mounts_yaml(Mounts("u1", {"u2": Mount("u2", mounted.matrix, -0.0032)})))
    return folder / "late.mcap", path


def test_rrd_draws_a_mounted_unit_in_the_references_axes_and_time(
        late: tuple[Path, Path], tmp_path: Path) -> None:
    archive, mounts = late
    out = tmp_path / "late.rrd"
    done = gx3("rrd", archive, "-o", out, "--mounts", mounts)
    assert done.returncode == 0, done.stderr
    store = RrdReader(out).stream().collect()
    ref, unit = (plot_values(store, "ang_rate", u) for u in ("u1", "u2"))
    times = [table(store, layout.plot_paths("ang_rate", u)[0]).column("time").to_pylist()
             for u in ("u1", "u2")]
    assert times[0] == times[1]  # the reference's instants, to the nanosecond
    np.testing.assert_allclose(unit, ref, atol=1e-5)  # float32 rates, turned
    prop = next(c.to_record_batch().to_pylist()[0] for c in RrdReader(out).stream()
                if c.entity_path == "/__properties/gx3_mounts")
    assert prop["sha256"] == [hashlib.sha256(mounts.read_bytes()).hexdigest()]
    assert prop["file"] == ["mounts.yaml"] and prop["reference"] == ["u1"]
    assert json.loads(prop["mounts"][0])["units"]["u2"]["time_shift_s"] == -0.0032


def test_rrd_refuses_a_mounts_file_of_other_units(late: tuple[Path, Path],
                                                  tmp_path: Path) -> None:
    archive, _ = late
    other = tmp_path / "other.yaml"
    other.write_text(mounts_yaml(Mounts("u1", {"u9": Mount("u9", np.eye(3))})))
    done = gx3("rrd", archive, "-o", tmp_path / "late.rrd", "--mounts", other)
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "--mounts other.yaml: unit u9 has no samples here (units: u1, u2)" in done.stderr
    assert not (tmp_path / "late.rrd").exists()
