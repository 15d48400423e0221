"""The compiled per-record core gives what the pure-Python paths give, byte for byte.

Where the package is installed without a C compiler or Python's headers, the core is
not built and the pure-Python paths run; these tests prove that nothing a user sees
depends on which one ran: the framer's records and counts, and every ImuSample
payload and its CRC-32 seal. Without the core they are skipped, and say why.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import shutil
import struct
import subprocess
import sys
import sysconfig
import termios
import threading
import time
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge import _native as native
from bridge.bus.codec import encode_records, native_layout
from bridge.bus.integrity import seals
from bridge.bus.publish import sealed_records
from bridge.device.port import Port
from bridge.exceptions import PortError
from bridge.protocol.codec import Records, checksum, native_checks, plausible
from bridge.protocol.framer import Framer
from bridge.protocol.table import BYTE_ORDER_REPLY, DATA_CODES, REPLIES, Flag
from tests.helpers.waiting import wait_for

CODES = sorted(DATA_CODES)
CORE = native.records
needs_core = pytest.mark.skipif(CORE is None, reason="the compiled core is not built here "
                                "(no C compiler or Python headers at install)")
needs_reader = pytest.mark.skipif(native.reader is None, reason="the compiled reader is not "
                                  "built here (no C compiler or Python headers at install)")
CHECKED = sorted(c for c in REPLIES if c != BYTE_ORDER_REPLY)
ROOT = Path(__file__).resolve().parents[1]


def python_intact(buf: bytes, start: int, code: int, little_endian: bool) -> int:
    """The framer's per-record rule, record after record, as the scanner applies it."""
    size = REPLIES[code].length
    good = 0
    while start + (good + 1) * size <= len(buf):
        rec = buf[start + good * size : start + (good + 1) * size]
        if (rec[0] != code or checksum(rec[:-2]) != (rec[-2] << 8 | rec[-1])
                or not plausible(code, rec, little_endian)):
            break
        good += 1
    return good


def summed(body: bytes) -> bytes:
    return body + struct.pack(">H", checksum(body))


@needs_core
@settings(max_examples=300, deadline=None)
@given(code=st.sampled_from(CHECKED), little_endian=st.booleans(), data=st.data())
def test_intact_counts_what_the_scanner_accepts(code: int, little_endian: bool,
                                                data: st.DataObject) -> None:
    """Records of random bytes with their sum made right, so the values decide: NaN,
    infinities, out-of-domain floats and integers, enumerations (0xDB's neighbours
    included); some with a flipped byte, a wrong header or a bad sum."""
    size = REPLIES[code].length
    n = data.draw(st.integers(1, 6), label="records")
    recs = []
    for i in range(n):
        body = bytes([code]) + data.draw(st.binary(min_size=size - 3, max_size=size - 3),
                                         label=f"body {i}")
        if data.draw(st.booleans(), label=f"small floats {i}"):
            body = bytes([code]) + bytes(b & 0x3F if k % 4 == (0 if little_endian else 1) else b
                                         for k, b in enumerate(body[1:], 1))
        rec = bytearray(summed(body))
        damage = data.draw(st.sampled_from(["none", "none", "sum", "header", "flip"]),
                           label=f"damage {i}")
        if damage == "sum":
            rec[-1] ^= 1
        elif damage == "header":
            rec[0] ^= 0x40
        elif damage == "flip":
            rec[data.draw(st.integers(0, size - 1))] ^= 0x10
        recs.append(bytes(rec))
    buf = b"\x00" * 3 + b"".join(recs) + b"\xc2"
    assert CORE is not None
    for start in (3, 3 + size * (n // 2)):
        limit = (len(buf) - start) // size
        assert CORE.intact(buf, start, size, code, limit, native_checks(code, little_endian)) \
            == python_intact(buf, start, code, little_endian)
    assert CORE.intact(buf, 3, size, code, 1, native_checks(code, little_endian)) <= 1


@needs_core
def test_intact_passes_non_finite_floats_and_refuses_finite_ones_out_of_domain() -> None:
    code = 0xCC
    size = REPLIES[code].length
    checks = native_checks(code, False)
    accel = REPLIES[code].offset("accel")
    for value, ok in [(float("nan"), True), (float("inf"), True), (-float("inf"), True),
                      (1.0, True), (1e30, False), (-1e30, False)]:
        body = bytearray(size - 2)
        body[0] = code
        body[accel : accel + 4] = struct.pack(">f", value)
        rec = summed(bytes(body))
        assert plausible(code, rec) is ok
        assert CORE is not None and CORE.intact(rec, 0, size, code, 1, checks) == int(ok)


def wire(code: int, n: int, seed: int) -> list[bytes]:
    """n records of ``code`` with random bytes: every bit pattern, NaN payloads included."""
    rng = np.random.default_rng(seed)
    return [bytes(r) for r in rng.integers(0, 256, (n, REPLIES[code].length), dtype=np.uint8)]


@needs_core
@pytest.mark.parametrize("little_endian", [False, True], ids=["big-endian", "little-endian"])
@pytest.mark.parametrize("code", CODES, ids=lambda c: f"0x{c:02X}")
def test_messages_are_the_encoders_bytes_and_seals(code: int, little_endian: bool) -> None:
    n = 7
    rng = np.random.default_rng(code)
    ticks = [0, -1, 2**63 - 1, -(2**63), *rng.integers(-(2**62), 2**62, n - 4).tolist()]
    time_ns = rng.integers(-(2**62), 2**62, n).tolist()
    rx_ns = rng.integers(0, 2**62, n).tolist()
    mono = rng.integers(0, 2**62, n).tolist()
    ago = rng.integers(0, 2**62, n).tolist()
    lead = rng.integers(0, 10**6, n).tolist()
    records = wire(code, n, code + little_endian)
    times = (ticks, time_ns, rx_ns, mono, ago, lead)
    for unit in ("u", "imu-0.a", "x" * 200):
        payloads = encode_records(unit, code, little_endian, records, times)
        assert CORE is not None
        assert CORE.messages(*native_layout(code, unit, little_endian), records,
                             times) == (payloads, seals(payloads))


@needs_core
def test_messages_refuses_what_it_cannot_lay_out() -> None:
    template, moves, at = native_layout(0xCC, "u", False)
    rec = wire(0xCC, 1, 0)
    assert CORE is not None
    more = ([5], [6])  # the partial read's columns
    with pytest.raises(ValueError, match="record 0"):
        CORE.messages(template, moves, at, [rec[0][:10]], ([1], [2], [3], [4], *more))
    with pytest.raises(ValueError, match="as long as wire"):
        CORE.messages(template, moves, at, rec, ([1, 2], [2], [3], [4], *more))
    with pytest.raises(ValueError, match="a position in at"):
        CORE.messages(template, moves, at, rec, ([1], [2], [3], *more))
    with pytest.raises(OverflowError):
        CORE.messages(template, moves, at, rec, ([2**64], [2], [3], [4], *more))
    with pytest.raises(ValueError, match="outside the message"):
        CORE.messages(template, moves, (0, 1, 2, 3, 4, len(template)), rec,
                      ([1], [2], [3], [4], *more))


def records_of(code: int, recs: list[bytes], little_endian: bool) -> Records:
    size = REPLIES[code].length
    return Records(code, little_endian, recs, [i * size for i in range(len(recs))],
                   [5] * len(recs))


@pytest.mark.parametrize("core", [True, False], ids=["core", "pure Python"])
def test_the_publishers_payloads_do_not_depend_on_the_core(
        core: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """What ``UnitPublisher.publish_records`` puts, with the core or without it."""
    if core and CORE is None:
        pytest.skip("the compiled core is not built here")
    if not core:
        monkeypatch.setattr(native, "records", None)
    recs = wire(0xCC, 3, 1)
    payloads, attachments = sealed_records("b", records_of(0xCC, recs, False), [1, 2, 3],
                                           [4, 5, 6], [7, 8, 9], [1, 0, 3], [0, 0, 86])
    expected = encode_records("b", 0xCC, False, recs, ([1, 2, 3], [4, 5, 6], [7, 8, 9],
                                                       [5, 5, 5], [1, 0, 3], [0, 0, 86]))
    assert payloads == expected
    assert attachments == seals(expected)


def damaged_stream(seed: int) -> bytes:
    """0xCC records, then 0xDB turning floats little-endian, then more; with garbage, a
    bad sum, a flipped float and a record cut short in between."""
    rng = np.random.default_rng(seed)
    size = REPLIES[0xCC].length
    parts: list[bytes] = []
    for i in range(40):
        rec = bytearray(summed(bytes([0xCC]) + bytes(size - 3)))
        if i == 7:
            rec[-1] ^= 1
        if i == 13:
            rec[1] = 0x7F  # accel x: 1e38-ish, finite, out of domain; sum made right
            rec[-2:] = struct.pack(">H", checksum(bytes(rec[:-2])))
        parts.append(bytes(rec))
        if i == 20:
            parts.append(rng.integers(0, 256, 30, dtype=np.uint8).tobytes())
        if i == 25:
            parts.append(bytes(rec[:40]))
        if i == 30:
            flags = REPLIES[BYTE_ORDER_REPLY]
            body = bytearray(flags.length - 2)
            body[0] = BYTE_ORDER_REPLY
            body[flags.offset("flags") : flags.offset("flags") + 2] = struct.pack(
                ">H", Flag.LITTLE_ENDIAN_FLOATS)
            body[flags.offset("decimation") + 1] = 1  # a big-endian u16
            body[flags.offset("filter_width")] = body[flags.offset("mag_filter_width")] = 1
            parts.append(summed(bytes(body)))
    return b"".join(parts)


@needs_core
@pytest.mark.parametrize("seed", range(4))
def test_the_framer_gives_the_same_records_and_counts_with_and_without_the_core(
        seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    stream = damaged_stream(seed)
    cuts = sorted(np.random.default_rng(seed).choice(len(stream), 60, replace=False).tolist())

    def run() -> tuple[list[tuple[int, bool, list[bytes], list[int]]], str]:
        framer = Framer(expect=[0xCC, BYTE_ORDER_REPLY])
        out = []
        for i, piece in enumerate(np.split(np.frombuffer(stream, np.uint8), cuts)):
            out += [(r.code, r.little_endian, r.wire, r.offsets)
                    for r in framer.feed_records([piece.tobytes()], [i])]
        out += [(b.code, b.little_endian, [bytes(row) for row in b.block], b.offsets.tolist())
                for b in framer.flush() if b.block is not None]
        return out, framer.stats.summary()

    with_core = run()
    monkeypatch.setattr(native, "records", None)
    assert run() == with_core
    assert "0xCC×38, 0xDB×1;" in with_core[1] and "implausible: 1;" in with_core[1]
    assert {little_endian for _, little_endian, _, _ in with_core[0]} == {False, True}


def test_a_machine_without_a_compiler_installs_the_pure_python_package(tmp_path: Path) -> None:
    """The README's set-up on a fresh machine with no compiler: the core's build fails,
    the wheel is built without it, and the package it installs runs pure Python."""
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source)
    shutil.copytree(ROOT / "bridge", source / "bridge",
                    ignore=shutil.ignore_patterns("__pycache__", "*.so"))
    env = {**os.environ, "CC": "false", "LDSHARED": "false"}
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                            "--no-build-isolation", "-w", str(tmp_path / "dist"), str(source)],
                           capture_output=True, text=True, timeout=300, check=False, env=env)
    assert built.returncode == 0, built.stderr
    (wheel,) = (tmp_path / "dist").glob("gx3_bridge-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "bridge/_native.py" in names
    assert not [n for n in names if n.startswith("bridge/_records") and n.endswith(".so")]
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    "--target", str(target), str(wheel)], check=True, timeout=300)
    probe = ("import bridge, bridge._native as n; from bridge.protocol.framer import Framer; "
             "print(bridge.__file__, n.records)")
    # -S and another folder: neither this checkout nor its editable install (a .pth
    # hook), only the wheel and the dependencies beside it
    path = os.pathsep.join([str(target), sysconfig.get_paths()["purelib"],
                            sysconfig.get_paths()["platlib"]])
    ran = subprocess.run([sys.executable, "-S", "-c", probe], capture_output=True, text=True,
                         cwd=tmp_path, timeout=60, check=True,
                         env={**os.environ, "PYTHONPATH": path})
    assert ran.stdout.split() == [str(target / "bridge" / "__init__.py"), "None"]


def test_where_the_core_can_be_built_the_install_built_it() -> None:
    """The core's tests skip where it is not built; a C file that no longer compiles
    would make them skip everywhere, and pass. Where a C compiler and Python's headers
    are at hand the install builds it, so there its absence fails."""
    compiler = (sysconfig.get_config_var("CC") or "").split()[:1]
    headers = Path(sysconfig.get_paths()["include"]) / "Python.h"
    if not compiler or shutil.which(compiler[0]) is None or not headers.is_file():
        pytest.skip("no C compiler or no Python headers here: the core cannot be built")
    if os.environ.get("GX3_NATIVE") == "0":
        pytest.skip("GX3_NATIVE=0 runs the pure-Python paths on purpose")
    missing = [name for name, core in (("_records", native.records), ("_gather", native.reader))
               if core is None]
    assert not missing, (f"bridge.{' and bridge.'.join(missing)} not built although "
                         f"{compiler[0]} and {headers} are here: reinstall, and read why the "
                         "build of bridge/*.c failed")


@contextmanager
def pty_port() -> Iterator[tuple[Port, int]]:
    """A Port on a real pseudo-terminal, and the master end that plays the unit."""
    master, slave = os.openpty()
    try:
        port = Port.open(os.ttyname(slave), 115_200)
        try:
            yield port, master
        finally:
            port.close()
    finally:
        os.close(slave)
        os.close(master)


@needs_reader
def test_a_port_reads_on_until_the_record_is_whole_keeping_each_read() -> None:
    """Half a record now and half later: one call, two reads with their own times (the
    framer and the clock use both), as two calls without the compiled reader give."""
    with pty_port() as (port, master):
        os.write(master, b"a" * 10)
        wait_for(lambda: queued(port) == 10, 30, "the first piece to reach the tty")

        def rest() -> None:  # once the first piece is read, however late that is
            wait_for(lambda: queued(port) == 0, 30, "the first piece to be read")
            os.write(master, b"b" * 10)

        later = threading.Thread(target=rest)
        later.start()
        try:
            before = time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW)
            reads, raws, reals = port.read_until(20, 30.0)
        finally:
            later.join()
        assert reads == [b"a" * 10, b"b" * 10]
        # each read stamped on both clocks, taken together
        assert before < raws[0] < raws[1] <= time.clock_gettime_ns(time.CLOCK_MONOTONIC_RAW)
        assert reals[0] < reals[1] <= time.time_ns()
        offsets = [real - raw for raw, real in zip(raws, reals, strict=True)]
        assert abs(offsets[1] - offsets[0]) < 1_000_000, "the clocks were read apart"


def queued(port: Port) -> int:
    """Bytes waiting in the tty for the port to read."""
    answer = fcntl.ioctl(port.raw.fileno(), termios.FIONREAD, b"\0\0\0\0")
    return int(struct.unpack("i", answer)[0])


@needs_reader
def test_a_port_read_that_times_out_gives_what_came() -> None:
    with pty_port() as (port, master):
        assert port.read_until(20, 0.05) == ([], [], [])
        os.write(master, b"c" * 7)
        reads, _, _ = port.read_until(20, 0.5)
        while sum(map(len, reads)) < 7:
            reads += port.read_until(20, 0.5)[0]
        assert b"".join(reads) == b"c" * 7


@needs_reader
def test_a_port_whose_device_went_away_says_so() -> None:
    master, slave = os.openpty()
    port = Port.open(os.ttyname(slave), 115_200)
    try:
        os.close(master)
        with pytest.raises(PortError, match="went away"):
            port.read_until(20, 5.0)
    finally:
        port.close()
        os.close(slave)


@pytest.mark.parametrize("seed", range(4))
def test_feeding_a_records_pieces_at_once_is_feeding_them_one_by_one(seed: int) -> None:
    stream = damaged_stream(seed)
    rng = np.random.default_rng(seed)
    cuts = sorted(rng.choice(len(stream), 300, replace=False).tolist())
    pieces = [p.tobytes() for p in np.split(np.frombuffer(stream, np.uint8), cuts)]
    pieces[5:5] = [b""]  # an empty read is no read
    times = list(range(len(pieces)))
    times[9] = times[10]  # of reads at one time the last stands for them

    def run(groups: list[int]) -> list[tuple[int, bool, bytes, int, int, int, int]]:
        """Each record: its type, byte order, bytes, offset, receive time and partial read."""
        framer = Framer(expect=[0xCC, BYTE_ORDER_REPLY])
        out = []
        for start, end in itertools.pairwise([0, *groups, len(pieces)]):
            for r in framer.feed_records(pieces[start:end], times[start:end]):
                size = REPLIES[r.code].length
                part_ns = r.part_ns or r.rx_ns
                part_bytes = r.part_bytes or [size] * len(r)
                out += [(r.code, r.little_endian, *one) for one in zip(
                    r.wire, r.offsets, r.rx_ns, part_ns, part_bytes, strict=True)]
        return out

    one_by_one = run(list(range(1, len(pieces))))
    assert one_by_one == run(sorted(rng.choice(len(pieces), 60, replace=False).tolist()))
    assert len(one_by_one) >= 38


def test_without_the_compiled_reader_a_port_gives_one_read_and_the_caller_reads_on(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(native, "reader", None)
    with pty_port() as (port, master):
        os.write(master, b"a" * 10)
        reads, raws, reals = port.read_until(20, 30.0)
        assert reads == [b"a" * 10] and len(raws) == len(reals) == 1
        assert port.read_until(20, 0.05) == ([], [], [])


@needs_core
def test_intact_refuses_checks_that_read_outside_a_record() -> None:
    rec = summed(bytes([0xCC]) + bytes(REPLIES[0xCC].length - 3))
    size = REPLIES[0xCC].length
    assert CORE is not None
    for bad in ([size - 2.0, 1, 4, 1, 0, 0, 1, 0], [1, 100, 4, 1, 0, 0, 1, 0],
                [1, 1, 3, 0, 0, 0, 1, 0], [1, 1, 4, 1, 0, 0, 1, 5], [1, 1, 4]):
        with pytest.raises(ValueError, match="bad size, start or checks"):
            CORE.intact(rec, 0, size, 0xCC, 1, struct.pack(f"={len(bad)}d", *bad))
