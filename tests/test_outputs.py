"""No command destroys a file: outputs that exist, are an input, or are being written.

Real `gx3` commands on real files; each case is judged by what is in the files
afterwards (bridge/archive/outputs.py holds the rules every command follows). Refusals
and failures run in this process; what needs a process (another process's lock, Ctrl-C,
a crash) runs `gx3` processes.
"""

from __future__ import annotations

import os
import signal
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from bridge.archive.outputs import create_locked, free_folder, lock_holder, staged
from bridge.archive.rawcapture import RawCaptureWriter
from bridge.archive.walk import read_archive
from bridge.archive.writer import numbered
from bridge.exceptions import OutputRefused
from bridge.ingest.replay import replay
from bridge.sim.capture import streaming_config, synthesize
from bridge.sim.motion import MotionConfig
from bridge.sim.serve import Simulator
from bridge.sim.unit import UnitConfig
from bridge.sim.usb import UsbDelivery
from tests.helpers.archives import samples_in, write_capture
from tests.helpers.cli import gx3_here
from tests.helpers.processes import GX3, bridge_process, recorder
from tests.helpers.units import TWO_UNITS
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config


def files_in(folder: Path) -> dict[str, bytes]:
    """Every file in ``folder`` (hidden ones too) with its bytes."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def one_line_error(done: subprocess.CompletedProcess[str], code: int, says: str) -> None:
    assert done.returncode == code, (done.args, done.stderr)
    assert says in done.stderr and "Traceback" not in done.stderr, (done.args, done.stderr)
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


#: Where a service finds nobody: were an output let through, it would end at once.
NOBODY = ["--connect", "tcp/127.0.0.1:9", "--mode", "client"]


def run_all(*commands: list[str | Path]) -> list[subprocess.CompletedProcess[str]]:
    """Run ``commands`` one after another in this process: exit code and stderr each."""
    out = []
    for command in commands:
        done = gx3_here(*command)
        out.append(subprocess.CompletedProcess(command, done.exit_code, "", done.stderr))
    return out


def write_captures(folder: Path, units: int, seconds: float, decimation: int) -> list[Path]:
    """Raw captures of ``units`` emulated units (one file each), as gx3 bridge writes."""
    config = streaming_config(UnitConfig(motion=MotionConfig(seed=3)), code=0xCC,
                              decimation=decimation)
    cap = synthesize(config, UsbDelivery(seed=3), seconds=seconds)
    meta = {"record": "0xCC", "decimation": str(decimation), "filter_width": "15",
            "baud": "115200", "transport": "usb"}
    paths = []
    for i in range(units):
        path = folder / f"raw{i}.mcap"
        writer = RawCaptureWriter(path, "gx3", f"u{i}", {**meta, "unit": f"u{i}"})
        for rx, data in zip(cap.rx_ns.tolist(), cap.data, strict=True):
            writer.write(data, rx)
        writer.close()
        paths.append(path)
    return paths


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A raw capture and the archive replayed from it."""
    folder = tmp_path_factory.mktemp("small")
    [capture] = write_captures(folder, 1, 10.0, 10)
    replay([capture], folder / "archive.mcap")
    return capture, folder / "archive.mcap"


@pytest.fixture(scope="module")
def large(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], Path]:
    """Captures and their archive big enough that rendering or replaying takes a while
    (4 units, 120 s at 500 Hz each)."""
    folder = tmp_path_factory.mktemp("large")
    captures = write_captures(folder, 4, 120.0, 2)
    replay(captures, folder / "archive.mcap", jobs=1)
    return captures, folder / "archive.mcap"


@pytest.fixture(scope="module")
def bridged(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    """An emulated unit bridged onto Zenoh towards a recorder's loopback port: (config for
    the recorder, config to join them). Whatever recorder runs gets its samples; the
    module's tests run their recorders one after another."""
    folder = tmp_path_factory.mktemp("bridged")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rec_cfg = zenoh_config(folder / "rec.json5", listen=[endpoint])
    join_cfg = zenoh_config(folder / "join.json5", connect=[endpoint])
    with Simulator(TWO_UNITS[:1], "pty") as sim, \
            bridge_process(sim.endpoints[0], join_cfg, "--unit", "a"):
        yield rec_cfg, join_cfg


@pytest.fixture
def fleet(bridged: tuple[Path, Path], tmp_path: Path) -> tuple[Path, Path, Path]:
    """The bridged unit's configs, and an empty folder for this test's outputs."""
    out = tmp_path / "out"
    out.mkdir()
    return (*bridged, out)


def ticks(path: Path) -> np.ndarray:
    return np.sort(np.concatenate([b.columns["ticks"]
                                   for b in read_archive(path).samples(["a"])]))


def stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGINT) -> bytes:
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=30)
    return stderr


def test_a_second_recorder_on_the_same_file_is_refused_naming_the_first(
        fleet: tuple[Path, Path, Path]) -> None:
    cfg, join_cfg, out = fleet
    path = out / "same.mcap"
    first = recorder(path, cfg)
    try:
        wait_for(lambda: samples_in(path, "a") >= 200, what="the first recorder's samples")
        [second] = run_all(["record", "-o", path, "--zenoh-config", join_cfg, "--quiet",
                            "--duration", "3"])
        one_line_error(second, 2, f"being written by process {first.pid}")
    finally:
        stderr = stop(first)
    assert first.returncode == 0, stderr.decode()
    archive = read_archive(path)
    assert archive.complete and archive.problem is None
    got = ticks(path)
    assert len(got) >= 200 and (np.diff(got) == 625).all(), "the first archive was damaged"
    assert [p.name for p in out.iterdir()] == ["same.mcap"]


def test_a_restarted_split_recorder_adds_parts_and_keeps_the_crashed_one(
        fleet: tuple[Path, Path, Path]) -> None:
    """What the shipped systemd unit does after a crash: the same command again."""
    cfg, _, out = fleet
    path = out / "fleet.mcap"
    first = recorder(path, cfg, "--split-minutes", "60")
    wait_for(lambda: samples_in(numbered(path, 1), "a") >= 200, what="the first part")
    stop(first, signal.SIGKILL)  # a crash: no summary, and the lock goes with the process
    before = numbered(path, 1).read_bytes()
    assert lock_holder(numbered(path, 1)) is None
    second = recorder(path, cfg, "--split-minutes", "60")
    try:
        wait_for(lambda: samples_in(numbered(path, 2), "a") >= 200, what="the second part")
    finally:
        stderr = stop(second)
    assert second.returncode == 0, stderr.decode()
    assert sorted(p.name for p in out.iterdir()) == ["fleet_0001.mcap", "fleet_0002.mcap"]
    assert numbered(path, 1).read_bytes() == before, "the first run's part was rewritten"
    assert not read_archive(numbered(path, 1)).complete and read_archive(numbered(path, 2)).complete
    assert ticks(numbered(path, 2))[0] > ticks(numbered(path, 1))[-1]
    [repaired] = run_all(["repair", numbered(path, 1)])
    assert repaired.returncode == 0, repaired.stderr
    assert len(ticks(out / "fleet_0001.repaired.mcap")) == len(ticks(numbered(path, 1)))


def test_existing_outputs_are_kept_unless_forced(small: tuple[Path, Path],
                                                 tmp_path: Path) -> None:
    capture, archive = small
    names = ("rec.mcap", "replayed.mcap", "table.csv", "view.rrd", "render.rrd",
             "fixed.mcap", "raw.mcap")
    for name in names:
        (tmp_path / name).write_bytes(b"the user's " + name.encode())
    before = files_in(tmp_path)
    o = {name.split(".")[0]: tmp_path / name for name in names}
    refused = run_all(["record", "-o", o["rec"], "--duration", "0", *NOBODY],
                      ["replay", capture, "-o", o["replayed"]],
                      ["export", archive, "-o", o["table"]],
                      ["view", "--save", o["view"], "--duration", "0", *NOBODY],
                      ["rrd", archive, "-o", o["render"]],
                      ["repair", archive, "-o", o["fixed"]],
                      ["bridge", "--port", tmp_path / "no-such-port", "--capture", o["raw"]])
    for done in refused:
        one_line_error(done, 2, "exists; choose another name, or --force to replace it")
    assert files_in(tmp_path) == before
    forced = run_all(["replay", capture, "-o", o["replayed"], "--force"],
                     ["export", archive, "-o", o["table"], "--force"],
                     ["rrd", archive, "-o", o["render"], "--force"],
                     ["repair", archive, "-o", o["fixed"], "--force"])
    for done in forced:
        assert done.returncode == 0, (done.args, done.stderr)
    assert read_archive(o["replayed"]).complete and read_archive(o["fixed"]).complete
    assert o["table"].read_text().startswith('"unit",') and o["render"].stat().st_size > 1000
    assert sorted(files_in(tmp_path)) == sorted(names), "a temporary file was left"


def test_an_output_that_is_an_input_is_refused_even_with_force(
        small: tuple[Path, Path], tmp_path: Path) -> None:
    capture, archive = small
    alias = tmp_path / "alias.mcap"
    alias_csv = tmp_path / "alias.csv"
    alias_rrd = tmp_path / "alias.rrd"
    for name in (alias, alias_csv, alias_rrd):
        os.link(archive, name)  # another name, the same file
    before = archive.read_bytes(), capture.read_bytes()
    commands: list[list[str | Path]] = [
        ["rrd", archive, "-o", alias_rrd],
        ["replay", capture, "-o", capture],
        ["export", archive, "-o", tmp_path / "t.csv", "--events", alias_csv],
        ["repair", archive, "-o", alias]]
    forces: tuple[list[str | Path], ...] = ([], ["--force"])
    runs = run_all(*[c + force for force in forces for c in commands])
    for done in runs:
        one_line_error(done, 2, "is the input")
    assert (archive.read_bytes(), capture.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alias.csv", "alias.mcap",
                                                          "alias.rrd"]


def interrupt_once_writing(command: list[str | Path], folder: Path) -> tuple[int, str]:
    """Start ``command`` in its own process group, Ctrl-C it (SIGINT to the group, as a
    terminal does) once it has begun writing a file in ``folder``: (exit code, stderr)."""
    def started() -> bool:
        try:
            return any(p.stat().st_size > 0 for p in folder.iterdir())
        except FileNotFoundError:  # a file gone between listing and looking
            return False

    assert not started()
    proc = subprocess.Popen([GX3, *map(str, command)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for(started, what="the output to be started")
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, stderr


def test_ctrl_c_leaves_no_partial_output(large: tuple[list[Path], Path],
                                         tmp_path: Path) -> None:
    captures, archive = large
    code, stderr = interrupt_once_writing(["rrd", archive, "-o", tmp_path / "x.rrd"],
                                          tmp_path)
    # Rerun may add a warning of its own about data it drops at exit
    assert code == 130 and "Traceback" not in stderr, stderr
    assert stderr.strip().endswith(f"{tmp_path / 'x.rrd'} was not written"), stderr
    assert files_in(tmp_path) == {}
    code, stderr = interrupt_once_writing(["replay", *captures, "-j", "2", "-o",
                                           tmp_path / "x.mcap"], tmp_path)
    assert code == 130 and "Traceback" not in stderr, stderr
    assert stderr.strip().endswith(f"{tmp_path / 'x.mcap'} was not written"), stderr
    assert files_in(tmp_path) == {}


def test_failures_leave_no_output_and_say_so_in_one_line(
        small: tuple[Path, Path], tmp_path: Path) -> None:
    capture, archive = small
    unreadable = tmp_path / "junk.mcap"
    unreadable.write_bytes(b"not an archive")
    rng = np.random.default_rng(1)
    garbage = write_capture(tmp_path / "garbage.mcap", [(i, rng.bytes(64)) for i in range(500)])
    no_samples = tmp_path / "empty.mcap"
    replay([], no_samples)
    inputs = files_in(tmp_path)
    missing = tmp_path / "missing" / "dir"
    cases: list[tuple[list[str | Path], int, str]] = [
        (["replay", garbage, "-o", tmp_path / "r.mcap"], 2, "no record found"),
        (["replay", archive, "-o", tmp_path / "r2.mcap"], 2, "no raw reads in it"),
        (["rrd", no_samples, "-o", tmp_path / "r.rrd"], 2, "no samples"),
        (["export", archive, "-o", tmp_path / "r.csv", "--unit", "nobody"], 2,
         "no samples match"),
        (["rrd", archive, "-o", missing / "y.rrd"], 2, "does not exist"),
        (["record", "--rrd", missing / "x.rrd", "--duration", "0", *NOBODY], 2,
         "does not exist"),
        (["view", "--save", missing / "x.rrd", "--duration", "0", *NOBODY], 2,
         "does not exist"),
        (["replay", capture, "-o", missing / "x.mcap"], 2, "does not exist"),
        (["record", "-o", missing / "x.mcap", "--duration", "0", *NOBODY], 2,
         "does not exist"),
    ]
    cases += [([command, unreadable, "-o", tmp_path / f"r{suffix}"], 2, "not an MCAP file")
              for command, suffix in (("export", ".csv"), ("repair", ".mcap"),
                                      ("rrd", ".rrd"), ("replay", ".mcap"))]
    for done, (_, code, says) in zip(run_all(*[c for c, _, _ in cases]), cases, strict=True):
        one_line_error(done, code, says)
    assert files_in(tmp_path) == inputs, "a failed command left a file"


def test_a_second_demo_in_the_same_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "demo.mcap").write_bytes(b"an earlier demo")
    [done] = run_all(["demo", "-o", tmp_path])
    one_line_error(done, 2, "holds an earlier run's files")
    assert files_in(tmp_path) == {"demo.mcap": b"an earlier demo"}


def test_a_demo_with_no_folder_given_takes_the_next_free_one(tmp_path: Path) -> None:
    base = tmp_path / "gx3-demo"
    assert free_folder(base, next_free=True) == base
    (base / "run").mkdir(parents=True)
    (tmp_path / "gx3-demo-2").mkdir()  # empty: free
    assert free_folder(base, next_free=True) == tmp_path / "gx3-demo-2"
    (tmp_path / "gx3-demo-2" / "demo.mcap").write_bytes(b"")
    assert free_folder(base, next_free=True) == tmp_path / "gx3-demo-3"
    assert free_folder(base, force=True) == base
    with pytest.raises(OutputRefused, match="earlier run"):
        free_folder(base)


def test_a_locked_file_names_its_holder_and_is_never_replaced(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    with create_locked(path) as stream:
        stream.write(b"live data")
        stream.flush()
        assert lock_holder(path) == os.getpid()
        for force in (False, True):
            with pytest.raises(OutputRefused, match=f"being written by process {os.getpid()}"):
                create_locked(path, force)
            with pytest.raises(OutputRefused, match="being written"), staged(path, force=force):
                pass
    assert lock_holder(path) is None and path.read_bytes() == b"live data"
    with create_locked(path, force=True) as stream:
        stream.write(b"new")
    assert path.read_bytes() == b"new"


def test_a_staged_output_never_lands_on_a_file_that_appeared_meanwhile(
        tmp_path: Path) -> None:
    path = tmp_path / "out.csv"
    with pytest.raises(OutputRefused, match="appeared while it was being written"), \
            staged(path) as temp:
        temp.write_text("mine")
        path.write_text("someone else's")
    assert files_in(tmp_path) == {"out.csv": b"someone else's"}
    with pytest.raises(KeyboardInterrupt), staged(tmp_path / "b.csv") as temp:
        temp.write_text("half")
        raise KeyboardInterrupt
    assert files_in(tmp_path) == {"out.csv": b"someone else's"}

