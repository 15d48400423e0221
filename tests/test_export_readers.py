"""An export read by the tools it lands in: pandas, polars and DuckDB see the same values with
their types intact (UTC timestamps, float32, integers, nulls in aligned gaps), every column
name works unquoted in SQL and as an attribute, and the file says what its columns mean."""

from __future__ import annotations

import hashlib
import json
import keyword
import subprocess
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd  # type: ignore[import-untyped]
import polars as pl
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from bridge.bus.gx3_pb2 import Info
from bridge.export.describe import SCHEMA_VERSION, column_metadata, unit_labels
from tests.helpers.archives import write_two_units
from tests.helpers.processes import GX3

UNITS = ("IMU-1", "imu2")  # a name that is no identifier, and one that is
INFO = Info(unit="IMU-1", serial="6225.01234", firmware=1127, firmware_text="1.1.27",
            decimation=10, filter_width=15, command=0xC8, baud=115_200, link="usb",
            model_name="3DM-GX3-25", output_rate_hz=100.0)
# a null in a u2 column: the 0.3 s gap, and before u2's first / after its last sample
GAP = (0.011 + 39 * 0.025, 0.011 + 52 * 0.025)


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The archive, its plain and aligned Parquet export, the events file and a CSV."""
    folder = tmp_path_factory.mktemp("readers")
    files = {"archive": folder / "two.mcap", "plain": folder / "plain.parquet",
             "aligned": folder / "aligned.parquet", "events": folder / "events.parquet",
             "csv": folder / "aligned.csv"}
    write_two_units(files["archive"], UNITS, {"IMU-1": INFO})
    runs = [("-o", files["plain"], "--events", files["events"]),
            ("-o", files["aligned"], "--align", "50", "--end", "1.9"),
            ("-o", files["csv"], "--align", "50")]
    assert GX3
    procs = [subprocess.Popen([GX3, "export", str(files["archive"]), *map(str, args)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for args in runs]  # side by side: each start costs a second
    for proc in procs:
        _, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr
    return files


def test_pandas_polars_and_duckdb_read_one_row_per_sample_with_types_intact(
        exported: dict[str, Path]) -> None:
    path = exported["plain"]
    schema = pq.read_schema(path)
    assert schema.field("time_utc").type == pa.timestamp("ns", tz="UTC")
    assert schema.field("time_ns").type == pa.int64()
    assert schema.field("accel_x").type == pa.float32()
    assert schema.field("command").type == pa.uint8()
    chunks = pq.ParquetFile(path).metadata.row_group(0)
    stored = {chunks.column(i).path_in_schema: chunks.column(i).encodings
              for i in range(chunks.num_columns)}  # what every reader below must decode
    assert "DELTA_BINARY_PACKED" in stored["time_utc"] and "DELTA_BINARY_PACKED" in stored["rx_ns"]
    assert "BYTE_STREAM_SPLIT" in stored["accel_x"]

    frame = pd.read_parquet(path)
    assert str(frame.time_utc.dtype) == "datetime64[ns, UTC]"
    assert frame.accel_x.dtype == np.float32 and frame.ticks.dtype == np.int64
    assert (frame.time_utc == pd.to_datetime(frame.time_ns, unit="ns", utc=True)).all()
    assert set(frame.unit.astype(str)) == set(UNITS)

    table = pl.read_parquet(path)
    assert table.schema["time_utc"] == pl.Datetime("ns", "UTC")
    assert table.schema["accel_x"] == pl.Float32 and table.schema["timer"] == pl.UInt32
    assert (table["time_utc"].dt.epoch("ns") == table["time_ns"]).all()
    np.testing.assert_array_equal(table["accel_x"].to_numpy(), frame.accel_x.to_numpy())

    with duckdb.connect() as db:
        types = db.sql(f"DESCRIBE SELECT * FROM read_parquet('{path}')").fetchall()
        typed = {name: kind for name, kind, *_ in types}
        assert typed["time_utc"] == "TIMESTAMPTZ_NS"  # nanoseconds and the zone kept
        assert (typed["accel_x"], typed["time_ns"]) == ("FLOAT", "BIGINT")
        rows = db.sql(f"SELECT unit, count(*), sum(accel_x), min(epoch_ns(time_utc)) "
                      f"FROM read_parquet('{path}') GROUP BY unit ORDER BY unit").fetchall()
    for unit, count, total, first in rows:
        mine = frame[frame.unit == unit]
        assert count == len(mine) and first == mine.time_ns.min()
        assert total == pytest.approx(float(mine.accel_x.astype(np.float64).sum()), rel=1e-6)


def test_aligned_gaps_are_nulls_to_every_reader(exported: dict[str, Path]) -> None:
    path = exported["aligned"]
    column = "imu2__accel_x"
    arrow = pq.read_table(path)
    grid_s = (np.asarray(arrow.column("time_ns")) - arrow.column("time_ns")[0].as_py()) / 1e9
    nulls = arrow.column(column).is_null().to_numpy(zero_copy_only=False)
    assert nulls.sum() >= 15  # the gap (≥ 0.3 s at 50 Hz) and u2's start
    assert nulls[(grid_s > GAP[0] + 0.01) & (grid_s < GAP[1] - 0.01)].all()

    frame = pd.read_parquet(path)
    assert (frame.imu2__accel_x.isna().to_numpy() == nulls).all()
    table = pl.read_parquet(path)
    assert table[column].null_count() == nulls.sum()
    assert table[column].is_nan().sum() == 0  # polars tells NaN from null: none are NaN
    assert table[column].dtype == pl.Float32
    with duckdb.connect() as db:
        (missing, nans, mean), = db.sql(
            f"SELECT count(*) - count({column}), count(*) FILTER (WHERE isnan({column})), "
            f"avg({column}) FROM read_parquet('{path}')").fetchall()
    assert (missing, nans) == (nulls.sum(), 0)
    assert np.isfinite(mean)  # a NaN would poison the average; a null is left out


def test_csv_time_utc_and_empty_gaps_read_back_typed(exported: dict[str, Path]) -> None:
    table = pa_csv.read_csv(exported["csv"])
    assert table.schema.field("time_utc").type == pa.timestamp("ns", tz="UTC")
    np.testing.assert_array_equal(table.column("time_utc").cast(pa.int64()),
                                  table.column("time_ns"))
    assert table.column("imu2__m33").null_count > 0
    with duckdb.connect() as db:
        (kind, nulls), = db.sql(
            f"SELECT typeof(any_value(time_utc)), count(*) - count(imu2__m33) "
            f"FROM read_csv('{exported['csv']}')").fetchall()
    assert (kind, nulls) == ("TIMESTAMP WITH TIME ZONE", table.column("imu2__m33").null_count)


def test_csv_headers_say_each_columns_unit_and_every_reader_takes_them(
        exported: dict[str, Path]) -> None:
    """CSV has no metadata: a column's unit is in its header, ``accel_x [g]``, which
    pandas, polars and DuckDB read with no option; the unit is the one a Parquet file's
    field metadata gives."""
    path = exported["csv"]
    frame = pd.read_csv(path)
    table = pl.read_csv(path)
    with duckdb.connect() as db:
        names = [n for n, *_ in db.sql(f"DESCRIBE SELECT * FROM read_csv('{path}')").fetchall()]
        (mean,), = db.sql(f"SELECT avg(\"imu2__accel_x [g]\") FROM read_csv('{path}')"
                          ).fetchall()
    assert list(frame.columns) == table.columns == names
    assert {"time_ns", "time_utc", "imu2__accel_x [g]", "imu_1__ang_rate_z [rad/s]",
            "imu2__m33"} <= set(names)
    parquet = pq.read_schema(exported["aligned"])
    for name in names:
        bare, _, bracket = name.partition(" [")
        unit = (parquet.field(bare).metadata or {}).get(b"physical_unit", b"").decode()
        assert bracket == (f"{unit}]" if unit not in ("", "unitless", "ns") else ""), name
    assert mean == pytest.approx(frame["imu2__accel_x [g]"].mean())
    assert mean == pytest.approx(table["imu2__accel_x [g]"].mean())


def test_every_column_name_works_unquoted_in_sql_and_as_an_attribute(
        exported: dict[str, Path]) -> None:
    with duckdb.connect() as db:
        reserved = {k for (k,) in db.sql("SELECT keyword_name FROM duckdb_keywords()")
                    .fetchall()}
        for name in ("plain", "aligned", "events"):
            path = exported[name]
            names = pq.read_schema(path).names
            for column in names:
                assert column.isidentifier() and column == column.lower(), column
                assert not keyword.iskeyword(column) and column not in reserved, column
            # every column by its bare name, as someone would type it
            got = db.sql(f"SELECT {', '.join(names)} FROM read_parquet('{path}')").columns
            assert got == names
            frame = pd.read_parquet(path)
            for column in names:  # the column itself, not a DataFrame method of that name
                assert not hasattr(pd.DataFrame, column), column
                assert getattr(frame, column).equals(frame[column]), column
    assert "imu_1__m33" in pq.read_schema(exported["aligned"]).names


def test_unit_labels_are_identifiers_and_never_meet() -> None:
    labels = unit_labels(["IMU-1", "imu_1", "2nd", "imu.1"])
    assert labels == {"2nd": "unit_2nd", "IMU-1": "imu_1", "imu.1": "imu_1_2",
                      "imu_1": "imu_1_3"}
    assert all(label.isidentifier() for label in labels.values())


def test_the_file_says_what_its_columns_mean_and_where_it_came_from(
        exported: dict[str, Path]) -> None:
    schema = pq.read_schema(exported["aligned"])

    def field(name: str) -> dict[str, str]:
        return {k.decode(): v.decode() for k, v in (schema.field(name).metadata or {}).items()}

    assert field("imu_1__accel_x")["physical_unit"] == "g"
    assert field("imu_1__accel_x")["gx3_unit"] == "IMU-1"
    assert "body FRD" in field("imu2__ang_rate_z")["frame"]
    assert field("imu2__ang_rate_z")["physical_unit"] == "rad/s"
    assert column_metadata("roll", {})["physical_unit"] == "rad"
    assert "earth NED to body FRD" in field("imu2__m12")["frame"]
    assert field("time_ns")["physical_unit"] == "ns"
    assert "UTC" in field("time_utc")["description"]
    # quantities this archive lacks get theirs from gx3.proto too
    assert column_metadata("mag_x", {})["physical_unit"] == "gauss"
    assert column_metadata("raw_accel_y", {})["physical_unit"] == "A/D code"
    assert "scalar first" in column_metadata("q0", {})["frame"]
    assert column_metadata("temperature_2", {})["physical_unit"] == "A/D code"

    meta = {k.decode(): v.decode() for k, v in (schema.metadata or {}).items()}
    assert meta["gx3.schema"] == SCHEMA_VERSION
    assert meta["gx3.product"].startswith("gx3-bridge ")
    assert "NED" in meta["gx3.conventions"] and "scalar first" in meta["gx3.conventions"]
    archive = exported["archive"]
    assert json.loads(meta["gx3.source"]) == {
        "name": archive.name, "bytes": archive.stat().st_size,
        "sha256": hashlib.sha256(archive.read_bytes()).hexdigest()}
    options = json.loads(meta["gx3.export"])
    assert (options["align_hz"], options["end"]) == (50.0, "1.9")
    units = json.loads(meta["gx3.units"])
    assert units["imu2"] == {"column_prefix": "imu2", "info": None}
    info = units["IMU-1"]["info"]
    assert units["IMU-1"]["column_prefix"] == "imu_1"
    assert (info["serial"], info["firmware"], info["filter_width"], info["command"],
            info["link"], info["decimation"], info["baud"]) == (
        "6225.01234", 1127, 15, 0xC8, "usb", 10, 115_200)
    events = pq.read_schema(exported["events"]).metadata or {}
    assert events[b"gx3.schema"] == SCHEMA_VERSION.encode()
