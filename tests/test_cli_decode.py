"""`gx3 decode` and `gx3 commands`, run as the installed console script."""

from __future__ import annotations

import json
import math
import shutil
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
GX3 = shutil.which("gx3", path=str(Path(sys.executable).parent)) or shutil.which("gx3")


def gx3(*args: str, stdin: bytes = b"") -> subprocess.CompletedProcess[bytes]:
    assert GX3, "the gx3 console script is not installed next to this interpreter"
    return subprocess.run([GX3, *args], input=stdin, capture_output=True, timeout=60, check=False)


def frame(code: int, payload: bytes) -> bytes:
    body = bytes((code,)) + payload
    return body + struct.pack(">H", sum(body) % 65_536)


NAN = struct.pack(">f", math.nan)
C2 = frame(0xC2, struct.pack(">6fI", 0.5, -1.0, 2.0, 0.0, 0.25, -0.125, 0xFFFFFFF0))
C8 = frame(0xC8, struct.pack(">6f9fI", 1, 0, 0, 0, 0, 1, *(k / 16 for k in range(1, 10)), 7))
CB_NAN = frame(0xCB, struct.pack(">6f", 0, 0, -1, 0, 0, 0) + NAN * 3 + struct.pack(">I", 8))
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
     "mag": [None, None, None], "timer": 8},
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


def test_decode_reads_stdin(capture: Path) -> None:
    done = gx3("decode", "-", stdin=CAPTURE)
    assert done.returncode == 0
    assert done.stdout == gx3("decode", str(capture)).stdout


def test_little_endian_floats(tmp_path: Path) -> None:
    raw = frame(0xC2, struct.pack("<6f", 0.5, -1.0, 2.0, 0.0, 0.25, -0.125)
                + struct.pack(">I", 0xFFFFFFF0))
    path = tmp_path / "le.bin"
    path.write_bytes(raw * 2)
    done = gx3("decode", "--little-endian", str(path))
    assert done.returncode == 0
    assert lines(done.stdout) == [EXPECTED[0], EXPECTED[0]]


def test_expect_selects_settings_replies(tmp_path: Path) -> None:
    path = tmp_path / "replies.bin"
    path.write_bytes(frame(0xD4, b"\x02") + b"\x21\x00\x21" + C2)
    done = gx3("decode", "--expect", "0xD4", "-e", "0x21", str(path))
    assert done.returncode == 0
    assert lines(done.stdout) == [{"command": 0xD4, "mode": 2}, {"command": 0x21}]


def test_expect_rejects_a_code_no_reply_starts_with(capture: Path) -> None:
    done = gx3("decode", "--expect", "0x99", str(capture))
    assert done.returncode == 2
    assert b"0x99" in done.stderr
    assert b"Traceback" not in done.stderr


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


@pytest.mark.parametrize("content", [b"", b"\x00\x01\x02garbage\xff" * 50, C8[:40], C2 + C8[:40]],
                         ids=["empty", "garbage", "truncated", "record-then-truncated"])
def test_truncated_or_garbage_file_exits_zero_with_a_summary(
    tmp_path: Path, content: bytes
) -> None:
    path = tmp_path / "bad.bin"
    path.write_bytes(content)
    done = gx3("decode", str(path))
    assert done.returncode == 0
    decoded = lines(done.stdout)
    assert decoded == ([EXPECTED[0]] if content.startswith(C2) else [])
    (summary,) = done.stderr.decode().splitlines()
    assert summary.startswith("records: ")
    assert f"of {len(content)};" in summary


def test_docs_command_reference_is_generated_from_the_table() -> None:
    done = gx3("commands", "--markdown")
    assert done.returncode == 0
    assert (ROOT / "docs" / "commands.md").read_text(encoding="utf-8") == done.stdout.decode()
