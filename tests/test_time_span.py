"""--start and --end: an end that is not after the start is said as such, by every command
that takes them, in one line and before anything is written (``TimeSpan``, one check in
the library); never as "no samples match", which sends the user looking at the archive.

In-process (Typer's runner) on a small archive: two units over 2 s.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.archive.times import TimeSpan
from bridge.cli import app
from bridge.exceptions import TimeSpanError
from tests.helpers.archives import write_two_units
from tests.helpers.records import T0

#: An ISO time 1.5 s into the archive, against which an end in seconds is compared only
#: once the archive is read.
LATE = datetime.fromtimestamp(T0 / 1e9 + 1.5, UTC).isoformat()


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("span") / "two.mcap"
    write_two_units(path)
    return path


@pytest.mark.parametrize(("command", "span", "says"), [
    (["export", "-o", "{d}/t.csv"], ["--start", "30", "--end", "10"],
     "--end 10 is before --start 30, so no sample can lie between them; give an --end "
     "after the start"),
    (["export", "-o", "{d}/t.parquet"], ["--start", LATE, "--end", "0.5"],
     f"--end 0.5 is before --start {LATE}"),
    (["allan", "-o", "{d}/imu_{{unit}}.yaml"], ["--start", "1", "--end", "1"],
     "--end 1 is the same instant as --start 1"),
    (["calibrate-mag", "-u", "u1", "-o", "{d}/iron.json"], ["--start", LATE, "--end", "1"],
     f"--end 1 is before --start {LATE}"),
    (["rrd", "-o", "{d}/w.rrd"], ["--start", "30", "--end", "10"],
     "--end 10 is before --start 30"),
    (["rrd", "-o", "{d}/w.rrd"], ["--start", LATE, "--end", "0.5"],
     f"--end 0.5 is before --start {LATE}"),
    (["align", "-u", "u1", "-u", "u2", "-o", "{d}/m.yaml"], ["--start", LATE, "--end", "1"],
     f"--end 1 is before --start {LATE}"),
], ids=["export", "export, read first", "allan", "calibrate-mag, read first", "rrd",
        "rrd, read first", "align, read first"])
def test_an_end_before_the_start_is_said_so(archive: Path, tmp_path: Path,
                                            command: list[str], span: list[str],
                                            says: str) -> None:
    args = [command[0], str(archive), *(a.format(d=tmp_path) for a in command[1:]), *span]
    done = CliRunner().invoke(app, args, env={"COLUMNS": "300"})
    assert done.exit_code == 2, done.output
    assert says in done.stderr and done.stderr.startswith("error: "), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "no samples" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_span_is_checked_as_soon_as_it_can_be() -> None:
    """Two bounds of one kind before anything is read; an ISO time against seconds from
    the first sample once that sample's instant is known."""
    with pytest.raises(TimeSpanError, match="neither an ISO time"):
        TimeSpan("noon")
    with pytest.raises(TimeSpanError, match="before"):
        TimeSpan("2026-11-22T02:50:00Z", "2026-11-22T02:49:00Z")
    mixed = TimeSpan("2026-11-22T02:50:00Z", "10")
    first = int(datetime(2026, 11, 22, 2, 49, 45, tzinfo=UTC).timestamp()) * 10**9
    with pytest.raises(TimeSpanError, match="--end 10 is before --start 2026"):
        mixed.resolve(first)  # the end 02:49:55
    later = first + 10 * 10**9
    assert mixed.resolve(later) == (later + 5 * 10**9, later + 10 * 10**9)
    assert TimeSpan().resolve(first) == (None, None)
