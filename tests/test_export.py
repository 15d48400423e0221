"""`gx3 export` and `gx3 repair` from the command line: tables with the right rows, columns and
values; filters; events; one-line errors for bad input."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from bridge.archive.mcap_writer import MAGIC
from bridge.archive.walk import read_archive
from bridge.export.describe import flat_names
from bridge.export.tables import sample_table
from bridge.timing import Estimate
from tests.helpers.archives import FLEET, LATENCY, PERIOD, Written, write_fleet
from tests.helpers.processes import GX3, gx3
from tests.helpers.records import T0

HEAD = ["unit", "command", "timer", "ticks", "time_ns", "time_utc", "time_uncertainty_ns",
        "live_time_ns", "rx_ns"]
ROWS = sum(n for _, n, _ in FLEET.values())


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Written]:
    path = tmp_path_factory.mktemp("export") / "fleet.mcap"
    return path, write_fleet(path, chunk_size=8_000)


def test_flat_names_follow_the_design() -> None:
    assert flat_names("accel", 3) == ["accel_x", "accel_y", "accel_z"]
    assert flat_names("m", 9) == ["m11", "m12", "m13", "m21", "m22", "m23", "m31", "m32", "m33"]
    assert flat_names("euler", 3) == ["roll", "pitch", "yaw"]
    assert flat_names("quaternion", 4) == ["q0", "q1", "q2", "q3"]
    assert flat_names("temperature", 4) == [f"temperature_{i}" for i in range(4)]


@pytest.mark.parametrize("suffix", [".parquet", ".csv"])
def test_export_writes_one_row_per_sample_with_flat_columns(
        fleet: tuple[Path, Written], tmp_path: Path, suffix: str) -> None:
    path, written = fleet
    out = tmp_path / f"fleet{suffix}"
    result = gx3("export", path, "-o", out)
    assert result.returncode == 0, result.stderr
    assert f"wrote {ROWS} samples of 3 units" in result.stderr
    table = pq.read_table(out) if suffix == ".parquet" else pa_csv.read_csv(out)
    if suffix == ".csv":  # each column's unit in its header, where Parquet has metadata
        assert {"timer [tick (1/62500 s)]", "accel_x [g]", "ang_rate_z [rad/s]",
                "mag_y [gauss]", "time_ns", "time_utc", "m11", "q0"} <= set(table.column_names)
        table = table.rename_columns([n.split(" [")[0] for n in table.column_names])
    assert table.num_rows == ROWS
    assert table.column_names == [
        *HEAD, "accel_x", "accel_y", "accel_z", "ang_rate_x", "ang_rate_y", "ang_rate_z",
        "mag_x", "mag_y", "mag_z", "m11", "m12", "m13", "m21", "m22", "m23", "m31", "m32",
        "m33", "q0", "q1", "q2", "q3"]
    cols = {name: table.column(name).to_numpy(zero_copy_only=False)
            for name in table.column_names}
    for name in table.column_names[len(HEAD):]:  # CSV floats read back as float64
        cols[name] = cols[name].astype(np.float32)
    assert np.all(np.diff(cols["time_ns"]) >= 0)
    units = cols["unit"].astype(str)
    for unit, (code, n, _) in FLEET.items():
        mine = units == unit
        assert mine.sum() == n
        assert set(cols["command"][mine].tolist()) == {code}
        np.testing.assert_array_equal(cols["time_ns"][mine], written.times[unit])
        np.testing.assert_array_equal(cols["live_time_ns"][mine], written.times[unit])
        np.testing.assert_array_equal(cols["rx_ns"][mine], written.times[unit] + LATENCY)
        np.testing.assert_array_equal(cols["timer"][mine], written.batches[unit]["timer"])
        batch = written.batches[unit]
        if code == 0xDF:
            q = np.stack([cols[f"q{i}"][mine] for i in range(4)], axis=1)
            np.testing.assert_array_equal(q, batch["quaternion"])
            assert np.isnan(cols["accel_x"][mine]).all() and np.isnan(cols["m33"][mine]).all()
        else:
            acc = np.stack([cols[f"accel_{a}"][mine] for a in "xyz"], axis=1)
            np.testing.assert_array_equal(acc, batch["accel"])
            assert np.isnan(cols["q0"][mine]).all()
        if code == 0xCC:
            m = np.stack([cols[f"m{r}{c}"][mine] for r in "123" for c in "123"], axis=1)
            np.testing.assert_array_equal(m.reshape(-1, 3, 3), batch["m"])
            np.testing.assert_array_equal(cols["mag_z"][mine], batch["mag"][:, 2])


def test_filters_by_unit_type_and_time(fleet: tuple[Path, Written], tmp_path: Path) -> None:
    path, written = fleet
    out = tmp_path / "part.parquet"
    result = gx3("export", path, "-o", out, "--unit", "u1", "--unit", "u2", "--type", "0xCC",
                 "--start", "0.5", "--end", "1.5")
    assert result.returncode == 0, result.stderr
    table = pq.read_table(out)
    t = written.times["u1"]
    expected = t[(t >= T0 + PERIOD * 50) & (t < T0 + PERIOD * 150)]
    assert table.column("time_ns").to_pylist() == expected.tolist()
    assert set(table.column("unit").to_pylist()) == {"u1"}
    assert "q0" not in table.column_names
    iso = np.datetime_as_string(np.datetime64(T0 + PERIOD * 100, "ns"))
    late = tmp_path / "late.parquet"
    result = gx3("export", path, "-o", late, "--start", iso + "Z", "--unit", "u3")
    assert result.returncode == 0, result.stderr
    t3 = written.times["u3"]
    assert pq.read_table(late).column("time_ns").to_pylist() == t3[t3 >= T0 + PERIOD * 100].tolist()


def test_events_file_lists_every_event_per_unit(fleet: tuple[Path, Written],
                                                tmp_path: Path) -> None:
    path, written = fleet
    events = tmp_path / "events.csv"
    result = gx3("export", path, "-o", tmp_path / "s.csv", "--events", events)
    assert result.returncode == 0, result.stderr
    table = pa_csv.read_csv(events)
    assert table.column_names == ["unit", "time_ns", "time_utc", "ticks [tick (1/62500 s)]",
                                  "kind", "amount", "detail"]
    rows = table.to_pylist()
    assert [r["unit"] for r in rows] == ["u3", "u1", "u2"]  # in time order
    for r in rows:
        n = FLEET[r["unit"]][1]
        assert r["time_ns"] == written.times[r["unit"]][n // 2]
        assert (r["kind"], r["amount"], r["detail"]) == ("GAP", 3, "3 records missing")


def test_re_estimate_hook_replaces_time_ns_per_unit(fleet: tuple[Path, Written]) -> None:
    path, written = fleet
    calls: list[int] = []

    def re_estimate(unit: str, columns: Mapping[str, np.ndarray]) -> Estimate:
        ticks = columns["ticks"]
        calls.append(len(ticks))
        assert np.all(np.diff(columns["rx_ns"]) >= 0)
        return Estimate(T0 + ticks * 16_000, ticks % 7)  # 62.5 kHz ticks

    table = sample_table(read_archive(path), re_estimate=re_estimate)
    assert sorted(calls) == sorted(n for _, n, _ in FLEET.values())
    np.testing.assert_array_equal(table["time_ns"], T0 + table["ticks"] * 16_000)
    np.testing.assert_array_equal(table["time_uncertainty_ns"], table["ticks"] % 7)
    u1 = table["unit"] == "u1"
    np.testing.assert_array_equal(np.sort(table["live_time_ns"][u1]), written.times["u1"])


def test_repair_command_reports_what_it_kept(fleet: tuple[Path, Written],
                                             tmp_path: Path) -> None:
    path, _ = fleet
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:80_000])
    result = gx3("repair", cut, "-o", tmp_path / "ok.mcap")
    assert result.returncode == 0, result.stderr
    kept = read_archive(cut)
    assert f"recovered {kept.message_count} messages" in result.stdout
    assert f"dropped {kept.dropped_bytes} bytes" in result.stdout
    assert read_archive(tmp_path / "ok.mcap").complete
    result = gx3("export", cut, "-o", tmp_path / "cut.csv")
    assert result.returncode == 0 and "not finished" in result.stderr


def _bad_files(tmp_path: Path) -> dict[str, Path]:
    files = {"empty file": tmp_path / "empty.mcap", "not an MCAP file": tmp_path / "t.mcap",
             "nothing readable": tmp_path / "garbage.mcap"}
    files["empty file"].write_bytes(b"")
    files["not an MCAP file"].write_text("time,accel\n1,2\n")
    files["nothing readable"].write_bytes(MAGIC + bytes(range(256)) * 40)
    return files


def test_bad_input_gives_one_line_errors(fleet: tuple[Path, Written], tmp_path: Path) -> None:
    path, _ = fleet
    cases: list[tuple[list[str | Path], str]] = [(["export", f, "-o", tmp_path / "o.csv"], says)
             for says, f in _bad_files(tmp_path).items()]
    cases += [
        (["export", path, "-o", tmp_path / "o.xlsx"],
         "name the file .parquet, .csv, .mcap or .bag"),
        (["export", path, "-o", tmp_path / "o.csv", "--start", "noon"], "neither an ISO time"),
        (["export", path, "-o", tmp_path / "o.csv", "--unit", "nobody"], "no samples match"),
        (["export", path, "-o", tmp_path / "no" / "o.csv"], "does not exist"),
        (["repair", path, "-o", path], "is the input"),
    ]
    assert GX3
    runs = [(subprocess.Popen([GX3, *map(str, args)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "COLUMNS": "200"}), args, says)
            for args, says in cases]  # side by side: each start costs a second
    for proc, args, says in runs:
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 2, (args, stderr)
        assert says in stderr, (args, stderr)
        assert "Traceback" not in stderr
        assert len(stderr.strip().splitlines()) == 1, stderr
