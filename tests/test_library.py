"""gx3-bridge as a library other projects depend on: what its wheel ships (py.typed, the
.proto files, its version), that library code logs instead of printing, the JSON log
lines the long-running commands write for journald and log shippers, and the ranges
and pins its dependencies are installed at."""

from __future__ import annotations

import ast
import json
import logging
import re
import shutil
import signal
import subprocess
import sys
import tomllib
import zipfile
from datetime import datetime
from importlib.metadata import distribution, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import NormalizedName, canonicalize_name
from packaging.version import Version

import bridge
from bridge.sim.faults import FaultConfig
from bridge.sim.serve import Simulator
from tests.helpers.processes import Stderr, bridge_process
from tests.helpers.units import STATIC_UNIT
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import zenoh_config

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
# where people are talked to: the command line (rich, stdout, stderr) and `python -m bridge`
CLI_LAYER = (ROOT / "bridge" / "cli", ROOT / "bridge" / "__main__.py")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project's wheel, built from a copy of the sources with this venv's setuptools
    (no network, nothing left in the source tree)."""
    pytest.importorskip("setuptools", reason="building the wheel offline needs setuptools")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    for name in ("bridge", "schemas"):
        shutil.copytree(ROOT / name, src / name, symlinks=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         "--no-index", "-w", str(tmp / "dist"), str(src)],
        capture_output=True, text=True, timeout=300, check=False)
    if build.returncode != 0:
        pytest.skip(f"cannot build the wheel offline: {build.stderr.strip()[-300:]}")
    return next((tmp / "dist").glob("gx3_bridge-*.whl"))


def test_the_wheel_ships_the_typing_marker_and_the_schemas(wheel: Path) -> None:
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        assert "bridge/py.typed" in names
        for name in ("gx3.proto", "replies.json"):
            assert zf.read(f"bridge/schemas/{name}") == (ROOT / "schemas" / name).read_bytes()


def test_an_installed_wheel_finds_its_schemas_and_knows_its_version(
        wheel: Path, tmp_path: Path) -> None:
    """Installed alone (not the source tree, not the editable install): the package
    says where its .proto files are and which version it is."""
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                    "--target", str(target), str(wheel)], check=True, timeout=120)
    probe = ("import json, importlib.metadata, bridge; print(json.dumps({"
             "'file': bridge.__file__, 'version': bridge.__version__, "
             "'metadata': importlib.metadata.version('gx3-bridge'), "
             "'schemas': str(bridge.SCHEMAS_DIR)}))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True,
                         text=True, check=True, timeout=60,
                         env={"PYTHONPATH": str(target), "PATH": "/usr/bin:/bin"})
    found = json.loads(out.stdout)
    assert Path(found["file"]).is_relative_to(target)
    assert found["version"] == found["metadata"] == PYPROJECT["project"]["version"]
    schemas = Path(found["schemas"])
    assert schemas.is_relative_to(target)
    assert (schemas / "gx3.proto").read_bytes() == (ROOT / "schemas" / "gx3.proto").read_bytes()


def test_version_is_the_installed_metadata_and_pyproject() -> None:
    assert bridge.__version__ == version("gx3-bridge") == PYPROJECT["project"]["version"]
    assert (bridge.SCHEMAS_DIR / "gx3.proto").is_file()


def _talks_to_people(path: Path) -> list[str]:
    """Where a module prints, writes to stdout/stderr or uses rich."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        line = f"{path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                and node.func.id == "print":
            found.append(f"{line}: print()")
        elif isinstance(node, ast.Attribute) and node.attr in ("stdout", "stderr") \
                and isinstance(node.value, ast.Name) and node.value.id == "sys":
            found.append(f"{line}: sys.{node.attr}")
        elif isinstance(node, ast.Import | ast.ImportFrom):
            modules = [a.name for a in node.names] if isinstance(node, ast.Import) \
                else [node.module or ""]
            found += [f"{line}: import {m}" for m in modules if m.split(".")[0] == "rich"]
    return found


def test_library_modules_log_instead_of_printing() -> None:
    modules = [p for p in (ROOT / "bridge").rglob("*.py")
               if not any(p == c or p.is_relative_to(c) for c in CLI_LAYER)
               and not p.name.endswith("_pb2.py")]
    assert len(modules) > 30
    offenders = [hit for p in modules for hit in _talks_to_people(p)]
    assert not offenders, "library code talks to the terminal; use logging:\n" + \
        "\n".join(offenders)


def test_the_bridge_logs_json_lines_with_their_fields(tmp_path: Path) -> None:
    cfg = zenoh_config(tmp_path / "bridge.json5", listen=[f"tcp/127.0.0.1:{free_port()}"])
    with Simulator([STATIC_UNIT], "pty", faults=FaultConfig(drop_rate=0.002)) as sim, \
            bridge_process(sim.endpoints[0], cfg, "--unit", "lib1",
                           "--log-format", "json") as proc:
        stderr = Stderr(proc)
        wait_for(lambda: '"gap"' in stderr.read() or proc.poll() is not None,
                 what="a gap from a dropped byte")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        text = stderr.read()
    assert proc.returncode == 0, text
    lines = [json.loads(line) for line in text.splitlines()]  # every line is JSON
    for line in lines:
        assert {"time", "level", "logger", "message"} <= line.keys(), line
        assert datetime.fromisoformat(line["time"]).utcoffset() is not None
        assert line["level"] in ("debug", "info", "warning", "error")
    bring_up = next(line for line in lines if line.get("event") == "bring_up")
    assert bring_up["logger"] == "bridge.unit.service" and bring_up["level"] == "info"
    assert bring_up["message"].startswith("bring_up ") and "PIPE0001" in bring_up["message"]
    assert isinstance(bring_up["time_ns"], int)
    gap = next(line for line in lines if line.get("event") == "gap")
    assert gap["level"] == "warning" and gap["count"] >= 1, gap
    # a lone gap says how many went missing too, as a summed line does
    assert re.match(r"gap \([\d,]+ samples? missing", gap["message"]), gap
    # the command's own closing line comes as JSON too, not as text for a person
    assert any(line["logger"] == "gx3" and line["message"].startswith("lib1: ")
               for line in lines), lines


def test_log_level_and_format_reach_every_line(capfd: pytest.CaptureFixture[str]) -> None:
    from bridge.cli.common import LogFormat, LogLevel, err, log_to

    try:
        log_to(LogLevel.warning, LogFormat.json)
        logging.getLogger("bridge.archive.walk").info("an info line")
        logging.getLogger("bridge.archive.walk").warning("a warning", extra={"count": 3})
        err.print("[bold red]error:[/] a command's own error")
    finally:
        log_to()
    lines = [json.loads(line) for line in capfd.readouterr().err.splitlines()]
    assert [(x["level"], x["logger"], x["message"]) for x in lines] == [
        ("warning", "bridge.archive.walk", "a warning"),
        ("error", "gx3", "a command's own error")]
    assert lines[0]["count"] == 3


def _pins() -> dict[NormalizedName, Version]:
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            name, _, pinned = line.partition("==")
            assert pinned, f"constraints.txt: {line!r} is not an exact pin"
            pins[canonicalize_name(name)] = Version(pinned)
    return pins


def test_constraints_pin_every_installed_dependency() -> None:
    """Every distribution gx3-bridge[dev] pulls in (transitively) is pinned, at the
    version installed here."""
    pins, missing = _pins(), []
    todo, seen = [("gx3-bridge", frozenset({"dev"}))], set()
    while todo:
        name, extras = todo.pop()
        if (name, extras) in seen:
            continue
        seen.add((name, extras))
        dist = distribution(name)
        for text in dist.requires or []:
            req = Requirement(text)
            if req.marker is not None and not any(
                    req.marker.evaluate({"extra": e}) for e in extras | {""}):
                continue
            key = canonicalize_name(req.name)
            installed = Version(version(req.name))
            if pins.get(key) != installed:
                missing.append(f"{req.name}=={installed} (pinned: {pins.get(key)})")
            todo.append((req.name, frozenset(req.extras)))
    assert not missing, "constraints.txt lacks or mispins:\n" + "\n".join(sorted(set(missing)))


def test_runtime_dependencies_are_ranges_from_the_tested_version() -> None:
    """``>=`` the version CI tests (constraints.txt), ``<`` the next major (for 0.x, the
    next minor)."""
    pins = _pins()
    for text in PYPROJECT["project"]["dependencies"]:
        req = Requirement(text)
        specs = {s.operator: Version(s.version) for s in req.specifier}
        assert specs.keys() == {">=", "<"}, text
        low, high = specs[">="], specs["<"]
        assert pins[canonicalize_name(req.name)] == low, f"{text}: CI tests another version"
        expected = Version(str(low.major + 1)) if low.major else Version(f"0.{low.minor + 1}")
        assert high == expected, f"{text}: the upper bound is not the next major"
