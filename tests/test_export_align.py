"""`gx3 export --align`: units sampled at other instants and rates land on one grid, vectors
linearly, attitude by slerp, and nothing is invented inside a gap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from bridge.archive.walk import read_archive
from bridge.export.tables import align_table, sample_table
from bridge.protocol.convert import euler_to_m
from tests.helpers.archives import ACCEL_RATE, YAW_RATE, write_two_units
from tests.helpers.processes import gx3
from tests.helpers.records import T0


def test_aligned_rows_interpolate_vectors_and_attitude_and_leave_gaps_empty(
        tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    write_two_units(path)
    out = tmp_path / "aligned.parquet"
    result = gx3("export", path, "-o", out, "--align", "50")
    assert result.returncode == 0, result.stderr
    table = pq.read_table(out)
    grid = np.array(table.column("time_ns").to_pylist())
    assert np.all(np.diff(grid) == 20_000_000) and grid[0] % 20_000_000 == 0
    assert "u1__accel_x" in table.column_names and "u2__m33" in table.column_names
    s = (grid - T0) / 1e9
    for unit, first, last in (("u1", 0.003, 1.993), ("u2", 0.011, 1.986)):
        names = [f"{unit}__accel_x"] + [f"{unit}__m{r}{c}" for r in "123" for c in "123"]
        # no value is null, not NaN: nothing is a NaN, and the nulls are where NaN was
        assert not any(pc.any(pc.is_nan(table.column(n))).as_py() for n in names)
        nulls = [table.column(n).is_null().to_numpy(zero_copy_only=False) for n in names]
        assert all((n == nulls[0]).all() for n in nulls)
        acc = np.array(table.column(f"{unit}__accel_x").to_pylist(), float)
        assert (np.isnan(acc) == nulls[0]).all()
        m = np.stack([np.array(table.column(f"{unit}__m{r}{c}").to_pylist(), float)
                      for r in "123" for c in "123"], axis=1).reshape(-1, 3, 3)
        inside = (s >= first) & (s <= last)
        if unit == "u2":  # samples 40..51 missing: 1.011 s .. 1.311 s has no data
            gap = (s > 0.011 + 39 * 0.025) & (s < 0.011 + 52 * 0.025)
            assert gap.sum() >= 10
            assert np.isnan(acc[gap]).all() and np.isnan(m[gap]).all()
            inside &= ~gap
        assert np.isnan(acc[~inside]).all()
        np.testing.assert_allclose(acc[inside], ACCEL_RATE * s[inside], atol=1e-6)
        yaw = -1.0 + YAW_RATE * s[inside]
        truth = euler_to_m(np.stack([0 * yaw, 0 * yaw, yaw], axis=1))
        np.testing.assert_allclose(m[inside], truth, atol=2e-6)


def test_align_refuses_a_rate_that_is_not_positive(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    write_two_units(path)
    with pytest.raises(ValueError, match="positive rate"):
        align_table(sample_table(read_archive(path)), 0.0)
