"""Every output's name says what it holds: each command writes only under an extension
that names its format, and refuses any other in one line that names those that work,
before any work and without leaving a file (bridge/archive/outputs.py ``named_format``).

In-process (Typer's runner): each refusal comes before the command reads or opens
anything, so no process need start.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from bridge.archive.outputs import named_folder, named_format
from bridge.cli import app
from bridge.exceptions import OutputRefused

START = ["--start", "2026-11-28T06:00:00Z"]
#: Where a service finds nobody: were a name let through, it would end at once, not wait.
NOBODY = ["--connect", "tcp/127.0.0.1:9", "--mode", "client", "--duration", "0"]

#: (command line, with {d} for the folder; what the refusal names), an output of each
#: command that has one, each under a name for another format.
CASES = [
    (["import", "{d}/log.bin", "-u", "a", *START, "-o", "{d}/run.parquet"],
     "run.parquet: this writes an MCAP archive; name the file .mcap"),
    (["replay", "{d}/cap.mcap", "-o", "{d}/replayed.csv"], "name the file .mcap"),
    (["record", "-o", "{d}/fleet.parquet", *NOBODY], "name the file .mcap"),
    (["record", "-o", "{d}/fleet.mcap", "--rrd", "{d}/fleet.mcap.rrd2", *NOBODY],
     "this writes a Rerun recording; name the file .rrd"),
    (["export", "{d}/a.mcap", "-o", "{d}/table.txt"],
     "this writes a Parquet table, a CSV table, an MCAP archive or a ROS 1 bag; name the "
     "file .parquet, .csv, .mcap or .bag"),
    (["export", "{d}/a.mcap", "-o", "{d}/t.csv", "--events", "{d}/events.mcap"],
     "name the file .parquet or .csv"),
    (["rrd", "{d}/a.mcap", "-o", "{d}/a.mcap2"], "name the file .rrd"),
    (["view", "--save", "{d}/live.mcap", *NOBODY], "name the file .rrd"),
    (["allan", "{d}/a.mcap", "-o", "{d}/imu.json"],
     "this writes a YAML file; name the file .yaml or .yml"),
    (["allan", "{d}/a.mcap", "-o", "{d}/imu.yaml", "--plot", "{d}/allan.jpg"],
     "this writes a PNG image, an SVG image or a PDF document; name the file .png, .svg or "
     ".pdf"),
    (["allan", "{d}/a.mcap", "-u", "a", "-u", "b", "-o", "{d}/imu_{unit}.csv"],
     "name the file .yaml or .yml"),
    (["calibrate-mag", "{d}/a.mcap", "-o", "{d}/iron.yaml"],
     "this writes a JSON file; name the file .json"),
    (["calibrate-mag", "{d}/a.mcap", "-o", "{d}/iron.json", "--rrd", "{d}/fit.png"],
     "name the file .rrd"),
    (["repair", "{d}/a.mcap", "-o", "{d}/fixed.parquet"], "name the file .mcap"),
    (["bridge", "--port", "{d}/no-such-port", "--capture", "{d}/raw.bin", "--give-up-after",
      "1"], "name the file .mcap"),
    (["demo", "-o", "{d}/demo.mcap", "--units", "1", "--duration", "1"],
     "this writes a folder of files, and .mcap names a file"),
]


@pytest.mark.parametrize(("args", "says"), CASES,
                         ids=[f"{i}-{args[0]}" for i, (args, _) in enumerate(CASES)])
def test_an_output_named_for_another_format_is_refused_in_one_line(
        tmp_path: Path, args: list[str], says: str) -> None:
    for name in ("log.bin", "cap.mcap", "a.mcap"):
        (tmp_path / name).write_bytes(b"the user's " + name.encode())
    before = sorted(p.name for p in tmp_path.iterdir())
    done = CliRunner().invoke(app, [a.replace("{d}", str(tmp_path)) for a in args],
                              env={"COLUMNS": "300"})
    assert done.exit_code == 2, done.output
    assert says in done.stderr and done.stderr.startswith("error: "), done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_the_rule_takes_any_case_of_the_extensions_it_names() -> None:
    assert named_format(Path("RUN.MCAP"), ".mcap") == ".mcap"
    assert named_format(Path("imu.yml"), ".yaml", ".yml") == ".yml"
    with pytest.raises(OutputRefused, match=r"^run: this writes an MCAP archive; name the "
                                            r"file \.mcap$"):
        named_format(Path("run"), ".mcap")
    assert named_folder(Path("run-2026.11")) == Path("run-2026.11")  # a dot, not a format
