"""`gx3 decode` and `gx3 commands`, run as the installed console script."""

from __future__ import annotations

import json
import math
import os
import re
import select
import signal
import struct
import subprocess
from pathlib import Path
from typing import IO, Any

import pytest
from typer.testing import CliRunner

from bridge.archive.writer import ArchiveWriter
from bridge.cli import app
from bridge.protocol.table import COMMANDS
from tests.helpers.archives import write_capture
from tests.helpers.processes import GX3

ROOT = Path(__file__).resolve().parents[1]


def gx3(*args: str, stdin: bytes | None = None, columns: int = 80
        ) -> subprocess.CompletedProcess[bytes]:
    """``gx3 ARGS``: exit code, stdout and stderr in bytes. Fed ``stdin``, the console
    script (decode reads standard input's descriptor); else in this process."""
    if stdin is None:
        done = CliRunner().invoke(app, list(args), env={"COLUMNS": str(columns)})
        return subprocess.CompletedProcess(args, done.exit_code, done.stdout_bytes,
                                           done.stderr_bytes)
    env = {**os.environ, "COLUMNS": str(columns)}
    return subprocess.run([GX3, *args], input=stdin, capture_output=True, timeout=60,
                          check=False, env=env)


def frame(code: int, payload: bytes) -> bytes:
    body = bytes((code,)) + payload
    return body + struct.pack(">H", sum(body) % 65_536)


C2 = frame(0xC2, struct.pack(">6fI", 0.5, -1.0, 2.0, 0.0, 0.25, -0.125, 0xFFFFFFF0))
C8 = frame(0xC8, struct.pack(">6f9fI", 1, 0, 0, 0, 0, 1, *(k / 16 for k in range(1, 10)), 7))
CB_NAN = frame(0xCB, struct.pack(">6f3fI", 0, 0, -1, 0, 0, 0, math.nan, math.inf, -math.inf, 8))
D1 = frame(0xD1, struct.pack(">4HI", 2700, 2800, 2900, 3000, 9))
DF = frame(0xDF, struct.pack(">4fI", 1, 0, 0, 0, 10))
CAPTURE = b"\x00\xff" + C2 + C8 + CB_NAN + D1 + DF

EXPECTED: list[dict[str, Any]] = [
    {"command": 0xC2, "accel": [0.5, -1.0, 2.0], "ang_rate": [0.0, 0.25, -0.125],
     "timer": 4_294_967_280},
    {"command": 0xC8, "accel": [1.0, 0.0, 0.0], "ang_rate": [0.0, 0.0, 1.0],
     "m": [[1 / 16, 2 / 16, 3 / 16], [4 / 16, 5 / 16, 6 / 16], [7 / 16, 8 / 16, 9 / 16]],
     "timer": 7},
    {"command": 0xCB, "accel": [0.0, 0.0, -1.0], "ang_rate": [0.0, 0.0, 0.0],
     "mag": [None, None, None], "timer": 8},  # NaN, inf, -inf
    {"command": 0xD1, "temperature": [2700, 2800, 2900, 3000], "timer": 9},
    {"command": 0xDF, "quaternion": [1.0, 0.0, 0.0, 0.0], "timer": 10},
]


def lines(stdout: bytes) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stdout.decode().splitlines()]


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    path = tmp_path / "capture.bin"
    path.write_bytes(CAPTURE)
    return path


def test_decode_file_writes_one_json_object_per_record(capture: Path) -> None:
    done = gx3("decode", str(capture))
    assert done.returncode == 0, done.stderr.decode()
    assert lines(done.stdout) == EXPECTED
    assert b"NaN" not in done.stdout


def test_summary_is_one_line_on_stderr(capture: Path) -> None:
    done = gx3("decode", str(capture))
    (summary,) = done.stderr.decode().splitlines()
    assert summary == ("records: 0xC2×1, 0xC8×1, 0xCB×1, 0xD1×1, 0xDF×1; checksum failures: 0; "
                       "implausible: 0; "
                       f"bytes skipped: 2 of {len(CAPTURE)}; resyncs: 0")


def test_decode_reads_stdin() -> None:
    done = gx3("decode", "-", stdin=CAPTURE)
    assert done.returncode == 0
    assert lines(done.stdout) == EXPECTED


def test_floats_come_out_exactly_as_the_float32_sent() -> None:
    """Values that are not round in binary must read back as the very float32 sent."""
    values = (0.1, -0.2, 1e-5, 3.4e5, -1.17549435e-38, 9.80665)
    done = gx3("decode", "-", stdin=frame(0xC2, struct.pack(">6fI", *values, 1)))
    (record,) = lines(done.stdout)
    sent = struct.unpack(">6f", struct.pack(">6f", *values))
    assert tuple(record["accel"] + record["ang_rate"]) == sent


# Not round in binary: read in the wrong byte order, these floats are far out of range.
ODD = (0.1, -0.2, 0.3, 1.1, 2.2, 3.3)
LE_C2 = frame(0xC2, struct.pack("<6f", *ODD) + struct.pack(">I", 5))
BE_C2 = frame(0xC2, struct.pack(">6fI", *ODD, 5))
LE_VALUES = list(struct.unpack("<6f", LE_C2[1:25]))


def test_little_endian_floats(tmp_path: Path) -> None:
    path = tmp_path / "le.bin"
    path.write_bytes(LE_C2 * 2)
    done = gx3("decode", "--little-endian", str(path))
    assert done.returncode == 0
    assert [r["accel"] + r["ang_rate"] for r in lines(done.stdout)] == [LE_VALUES] * 2


def sampling_settings(flags: int) -> bytes:
    return frame(0xDB, struct.pack(">HHBBHH6x", 10, flags, 15, 17, 10, 10))


def test_decode_follows_byte_order_changes_in_the_capture() -> None:
    capture = C2 + sampling_settings(0x13) + LE_C2 + sampling_settings(0x03) + C2
    done = gx3("decode", "-", stdin=capture)
    assert done.returncode == 0
    decoded = lines(done.stdout)
    assert [r["command"] for r in decoded] == [0xC2, 0xDB, 0xC2, 0xDB, 0xC2]
    assert decoded[2]["accel"] + decoded[2]["ang_rate"] == LE_VALUES
    assert decoded[0] == decoded[4] == EXPECTED[0]


@pytest.mark.parametrize(("capture", "flags", "hint"), [
    (LE_C2 * 3, [], "try --little-endian"),
    (BE_C2 * 3, ["--little-endian"], "try without --little-endian"),
], ids=["little-read-as-big", "big-read-as-little"])
def test_nothing_decoded_fails_with_a_byte_order_hint_that_works(
    capture: bytes, flags: list[str], hint: str
) -> None:
    done = gx3("decode", *flags, "-", stdin=capture)
    assert done.returncode == 1
    assert done.stdout == b""
    summary, error = done.stderr.decode().splitlines()
    assert summary.startswith("records: none;")
    assert error.startswith("error: no record decoded, but 3 did with floats")
    assert error.endswith(hint)
    other = [] if flags else ["--little-endian"]
    retried = gx3("decode", *other, "-", stdin=capture)
    assert retried.returncode == 0
    assert len(lines(retried.stdout)) == 3


def test_expect_selects_settings_replies(tmp_path: Path) -> None:
    path = tmp_path / "replies.bin"
    path.write_bytes(frame(0xD4, b"\x02") + b"\x21\x00\x21" + C2)
    done = gx3("decode", "--expect", "0xD4", "-e", "0x21", str(path))
    assert done.returncode == 0
    assert lines(done.stdout) == [{"command": 0xD4, "mode": 2}, {"command": 0x21}]


@pytest.mark.parametrize("name", ["missing.bin", "run[/a] [bold]x.bin"])
def test_missing_file_is_a_one_line_error(tmp_path: Path, name: str) -> None:
    path = tmp_path / "a-directory-name-long-enough-to-push-the-message-past-80-columns" / name
    done = gx3("decode", str(path))
    assert done.returncode == 2
    assert done.stdout == b""
    text = done.stderr.decode()
    assert b"Traceback" not in done.stderr
    assert len(text.splitlines()) == 1
    assert text.startswith("error: ")
    assert str(path) in text


@pytest.mark.parametrize("content", [C2 + C8[:40], C8[:40] + C2], ids=["then-cut", "cut-then"])
def test_truncated_record_is_skipped_and_counted(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "bad.bin"
    path.write_bytes(content)
    done = gx3("decode", str(path))
    assert done.returncode == 0
    assert lines(done.stdout) == [EXPECTED[0]]
    (summary,) = done.stderr.decode().splitlines()
    assert "bytes skipped: 40 of" in summary


@pytest.mark.parametrize("source", ["-", "/dev/null"])
def test_empty_input_decodes_nothing_and_exits_1(source: str) -> None:
    done = gx3("decode", source, stdin=b"" if source == "-" else None)
    assert done.returncode == 1
    assert done.stdout == b""
    summary, error = done.stderr.decode().splitlines()
    assert summary.startswith("records: none;")
    assert error == "error: no record decoded: the input is empty"


@pytest.mark.parametrize("content", [
    b"\x00\x01\x02garbage\xff" * 50, C8[:40],
    b"\x00\x01\x02garbage\xff" * 50 + LE_C2 + b"\x00\x01\x02garbage\xff" * 50,
], ids=["garbage", "truncated", "garbage-with-one-chance-record-the-other-way"])
def test_nothing_decoded_from_garbage_exits_1(content: bytes) -> None:
    done = gx3("decode", "-", stdin=content)
    assert done.returncode == 1
    assert done.stdout == b""
    summary, error = done.stderr.decode().splitlines()
    assert f"of {len(content):,};" in summary
    assert error.startswith("error: no record decoded: ")
    assert "little-endian" not in error


def read_line(stream: IO[bytes], timeout: float = 30.0) -> bytes:
    """One line from a child's pipe, or fail after ``timeout`` seconds (generous)."""
    ready, _, _ = select.select([stream], [], [], timeout)
    assert ready, f"no output within {timeout} s"
    return stream.readline()


def test_records_leave_as_they_arrive_on_a_live_pipe() -> None:
    """The first record is written while the writer keeps the pipe open."""
    assert GX3
    with subprocess.Popen([GX3, "decode", "-"], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0) as proc:
        assert proc.stdin and proc.stdout and proc.stderr
        proc.stdin.write(C2)
        proc.stdin.flush()
        assert json.loads(read_line(proc.stdout)) == EXPECTED[0]
        proc.stdin.write(C8)
        proc.stdin.flush()
        assert json.loads(read_line(proc.stdout)) == EXPECTED[1]
        proc.stdin.close()
        assert proc.wait(timeout=60) == 0
        assert proc.stderr.read().decode().startswith("records: 0xC2×1, 0xC8×1;")


def test_ctrl_c_prints_the_summary_so_far_and_exits_130() -> None:
    """Quietly: stopping it is the user's choice (in a pipe from a serial reader, the one
    way to end both), not an error to report."""
    assert GX3
    with subprocess.Popen([GX3, "decode", "-"], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0) as proc:
        assert proc.stdin and proc.stdout and proc.stderr
        proc.stdin.write(C2 + C2)
        proc.stdin.flush()
        read_line(proc.stdout)
        read_line(proc.stdout)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=60) == 130
        proc.stdin.close()
        (summary,) = proc.stderr.read().decode().splitlines()
        assert summary.startswith("records: 0xC2×2;")


def test_docs_command_reference_is_generated_from_the_table() -> None:
    done = gx3("commands", "--markdown")
    assert done.returncode == 0
    assert (ROOT / "docs" / "commands.md").read_text(encoding="utf-8") == done.stdout.decode()


def test_command_list_fits_an_80_column_terminal() -> None:
    done = gx3("commands", columns=80)
    assert done.returncode == 0
    text = done.stdout.decode()
    assert max(len(line) for line in text.splitlines()) <= 80
    for code, cmd in COMMANDS.items():
        assert f"0x{code:02X}  {cmd.name}: " in text


def test_help_names_only_commands_that_exist() -> None:
    """Every `gx3 X` a help text mentions is a command (in-process: one start-up)."""
    runner = CliRunner()
    top = runner.invoke(app, ["--help"], env={"COLUMNS": "100"})
    existing = set(re.findall(r"│ ([a-z][\w-]*)\s{2,}", top.output))
    assert {"commands", "decode", "sim", "bridge", "record", "demo"} <= existing
    for name in existing:
        done = runner.invoke(app, [name, "--help"], env={"COLUMNS": "100"})
        assert done.exit_code == 0, name
        assert set(re.findall(r"gx3 ([\w-]+)", done.output)) <= existing, name


def test_usage_lines_name_each_argument_once() -> None:
    """A repeatable argument reads {LOG}..., not {LOG...}...: Typer adds the ellipsis to
    the metavar itself."""
    runner = CliRunner()
    top = runner.invoke(app, ["--help"], env={"COLUMNS": "100"})
    names = set(re.findall(r"│ ([a-z][\w-]*)\s{2,}", top.output))
    usages = {name: next(line for line in runner.invoke(
        app, [name, "--help"], env={"COLUMNS": "200"}).output.splitlines() if "Usage:" in line)
        for name in names}
    assert "{LOG}..." in usages["import"] and "{CAPTURE.mcap}..." in usages["replay"]
    assert not [u for u in usages.values() if "...}" in u or "......" in u], usages


def test_help_paragraphs_fill_an_80_column_terminal() -> None:
    """A command's description wraps at the terminal's width, not at its source's line
    breaks as well (which left lines of a word or two on 80 columns)."""
    runner = CliRunner()
    top = runner.invoke(app, ["--help"], env={"COLUMNS": "100"})
    for name in set(re.findall(r"│ ([a-z][\w-]*)\s{2,}", top.output)):
        text = runner.invoke(app, [name, "--help"], env={"COLUMNS": "80"}).output
        lines = [line.rstrip() for line in text.split("╭")[0].splitlines()]
        for paragraph in "\n".join(lines).split("\n\n"):
            lines = paragraph.strip("\n").splitlines()
            if lines and not lines[0].lstrip().startswith("Usage:"):
                short = [line for line in lines[:-1] if len(line) < 50]
                assert not short, (name, short)


@pytest.mark.parametrize(("value", "message"), [
    ("zz", "'zz' is not a number such as 0xC8"),
    ("0x99", "no reply starts with 0x99; replies start with 0x21 0xC1"),
])
def test_expect_errors_name_the_option_on_one_line(value: str, message: str) -> None:
    done = gx3("decode", "--expect", value, "-", stdin=C2)
    assert done.returncode == 2
    assert done.stdout == b""
    (line,) = done.stderr.decode().splitlines()
    assert line.startswith(f"error: --expect: {message}")


def test_a_bridges_mcap_capture_decodes_as_its_bytes_did(tmp_path: Path) -> None:
    """`gx3 bridge --capture` writes MCAP: decode reads its raw reads (cut anywhere, a
    record split across two reads) as it reads the same bytes off a line, each object
    led by the unit's name, and says what a file without raw reads is."""
    cut = len(CAPTURE) // 2
    capture = write_capture(tmp_path / "raw.mcap", [(1_000, CAPTURE[:cut]),
                                                    (2_000, CAPTURE[cut:])])
    done = gx3("decode", str(capture))
    assert done.returncode == 0, done.stderr.decode()
    assert lines(done.stdout) == [{"unit": "u1", **record} for record in EXPECTED]
    assert done.stderr.decode().startswith("u1: records: 0xC2×1, 0xC8×1, 0xCB×1, 0xD1×1, ")
    archive = tmp_path / "samples.mcap"
    ArchiveWriter(archive).close()
    refused = gx3("decode", str(archive))
    assert refused.returncode == 2
    assert refused.stderr.decode().count("\n") == 1 and "no raw reads" in refused.stderr.decode()
