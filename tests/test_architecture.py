"""The packages of ``bridge`` fit together as docs/design/architecture.md draws them.

Each package imports only those in the layers above its own (every import in
``bridge/``, read with ``ast``: inside functions and ``TYPE_CHECKING`` too), so no two
packages import each other; importing a package loads none of the heavy libraries it
does not need (each in a fresh interpreter); and the exception tree drawn in the
architecture page and in ``bridge/exceptions.py`` is the tree of the classes.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import re
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

import bridge.exceptions

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "bridge"
ARCHITECTURE = ROOT / "docs" / "design" / "architecture.md"
#: Modules of ``bridge`` itself that any package may import, and that import no package.
FOUNDATION = {"bridge", "bridge.exceptions", "bridge._lazy", "bridge._native", "bridge._text",
              "bridge._workers"}
#: The front doors, above every layer: ``bridge.subscribe`` (imported on first use), and
#: ``python -m bridge``.
FRONT = {"bridge/__init__.py", "bridge/__main__.py"}
#: The one exception the architecture page names: the names ``bridge.recorder`` declared
#: before the archive, ingest, export and analysis had packages of their own, still
#: declared there and imported on first use from their new homes.
KEPT_NAMES = {"bridge/recorder/__init__.py": {"ingest", "export", "analysis"}}
#: Heavy libraries, and what a package's import may load of them.
HEAVY = ("zenoh", "pyarrow", "rosbags", "rerun", "matplotlib", "polars", "pandas",
         "prometheus_client")
LOADS = {
    "bridge": (),
    "bridge.protocol": (),
    "bridge.device": (),
    "bridge.timing": (),
    "bridge.bus": (),
    "bridge.ros2": (),
    "bridge.archive": (),
    "bridge.unit.run": ("zenoh",),  # a live bridge: what gx3 bridge imports
    "bridge.recorder": (),
    "bridge.recorder.recording": ("zenoh",),  # gx3 record: Rerun only with --rrd
    "bridge.ingest": (),
    "bridge.analysis": (),
    "bridge.export": (),
    "bridge.viz": (),  # its Rerun and matplotlib parts load on first use
    "bridge.sim": (),
    "bridge.fleet": (),
    "bridge.cli": (),  # every gx3 command starts without them
}


def layers(text: str) -> list[set[str]]:
    """The layers the architecture page lists, top first: the first ``text`` block after
    its heading "Which package may import which", a line each."""
    section = text.split("## Which package may import which", 1)[1]
    block = re.search(r"```text\n(.*?)```", section, re.S)
    assert block is not None, "no ```text block of layers"
    return [set(re.split(r"\s+·\s+", line.split("  ")[0].strip()))
            for line in block.group(1).splitlines() if line.strip()]


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> Iterator[str]:
    """Every module a file imports, as a dotted name (relative imports resolved)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = _module(path).split(".")
    if path.name != "__init__.py":
        here = here[:-1]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*here[: len(here) - node.level + 1], *filter(None, [base])])
            yield base
            # ``from bridge import viz``: the names may be modules of their own
            yield from (f"{base}.{alias.name}" for alias in node.names
                        if _is_module(f"{base}.{alias.name}"))


def _is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def package_of(module: str) -> str | None:
    """The package of ``bridge`` a module belongs to (``bus``); None for one of the
    foundation or outside ``bridge``."""
    if module in FOUNDATION or not module.startswith("bridge."):
        return None
    return module.split(".")[1]


def violations(edges: Mapping[str, set[str]], stack: list[set[str]]) -> list[str]:
    """Each import (file -> packages it imports) that the layers do not allow."""
    level = {package: i for i, layer in enumerate(stack) for package in layer}
    found = []
    for file, imported in sorted(edges.items()):
        own = package_of(_module(ROOT / file))
        if own is None:  # the foundation imports no package
            found += [f"{file} imports {other}: the foundation imports no package"
                      for other in sorted(imported)]
            continue
        for other in sorted(imported - {own} - KEPT_NAMES.get(file, set())):
            if other not in level or own not in level:
                found.append(f"{file} imports {other}: {own if own not in level else other} "
                             "is in no layer of docs/design/architecture.md")
            elif level[other] >= level[own]:
                found.append(f"{file} ({own}) imports {other}, which is "
                             + ("in its own layer" if level[other] == level[own] else "below it"))
    return found


def cycles(edges: Mapping[str, set[str]]) -> list[list[str]]:
    """The cycles among packages that import each other (through any of their files)."""
    graph: dict[str, set[str]] = {}
    for file, imported in edges.items():
        own = package_of(_module(ROOT / file))
        if own is not None:
            graph.setdefault(own, set()).update(imported - {own})
    found: list[list[str]] = []
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for other in sorted(graph.get(node, ())):
            if state.get(other) == 1:
                found.append([*path[path.index(other):], other])
            elif other not in state:
                visit(other, [*path, other])
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return found


def package_imports() -> dict[str, set[str]]:
    """Each file of ``bridge`` (the front doors aside) -> the packages it imports."""
    edges = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        file = str(path.relative_to(ROOT))
        if file not in FRONT:
            edges[file] = {p for m in imports(path) if (p := package_of(m)) is not None}
    return edges


def test_every_package_imports_only_the_layers_above_it() -> None:
    stack = layers(ARCHITECTURE.read_text(encoding="utf-8"))
    assert violations(package_imports(), stack) == []


def test_every_package_is_in_one_layer() -> None:
    stack = layers(ARCHITECTURE.read_text(encoding="utf-8"))
    listed = [package for layer in stack for package in layer]
    packages = sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py"))
    assert sorted(listed) == packages


def test_no_two_packages_import_each_other() -> None:
    assert cycles(package_imports()) == []


def test_the_checks_find_what_breaks_the_layers() -> None:
    """The checks above pass trivially if they see nothing: they see what is there, and
    they see an import upward, one across a layer and a cycle."""
    stack = layers(ARCHITECTURE.read_text(encoding="utf-8"))
    assert len(stack) >= 10 and {"archive"} in stack
    edges = package_imports()
    assert "bus" in edges["bridge/archive/writer.py"]
    assert "analysis" in edges["bridge/export/run.py"]
    bad = {"bridge/archive/writer.py": {"bus", "recorder"},
           "bridge/unit/run.py": {"recorder"},
           "bridge/recorder/live.py": {"archive"},
           "bridge/_text.py": {"protocol"}}
    assert violations(bad, stack) == [
        "bridge/_text.py imports protocol: the foundation imports no package",
        "bridge/archive/writer.py (archive) imports recorder, which is below it",
        "bridge/unit/run.py (unit) imports recorder, which is in its own layer",
    ]
    assert cycles(bad) == [["archive", "recorder", "archive"]]
    assert _module(ROOT / "bridge/recorder/__init__.py") == "bridge.recorder"
    assert "bridge.archive.reader" in set(imports(ROOT / "bridge" / "viz" / "sources.py"))


@pytest.mark.parametrize("module", sorted(LOADS))
def test_importing_a_package_loads_only_what_it_needs(module: str) -> None:
    """A live bridge, the archive, the protocol, ``gx3`` itself: none loads what only
    other work needs (Zenoh, pyarrow, rosbags, Rerun, matplotlib, polars, pandas,
    prometheus_client), so each starts fast and installs nothing it does not use."""
    code = (f"import sys, json, {module}; "
            f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}})))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    loaded = set(json.loads(done.stdout)) & set(HEAVY)
    assert loaded == set(LOADS[module]), f"import {module} loads {sorted(loaded)}"


#: What ``bridge.recorder`` declared when it held the archive, ingest, export and analysis.
DECLARED_BEFORE = [
    "NOISE_KEYS", "About", "AllanSums", "ArchiveReader", "ArchiveWriter", "ArchivedSamples",
    "CapturedReads", "ChannelInfo", "Damage", "HostView", "Imported", "IronCalibration",
    "LogFile", "Messages", "NoiseFit", "RawCaptureWriter", "Record", "Recorder",
    "RepairReport", "Replayed", "Ros2Written", "SensorNoise", "UnitIron", "UnitNoise",
    "UnitSamples", "align_table", "averaging_factors", "capture_metadata", "captures",
    "collect_samples", "describe_problem", "event_table", "fit", "import_logs", "kalibr_yaml",
    "name_time", "offline_times", "parse_start", "read_archive", "read_document", "read_off",
    "repair", "replay", "sample_table", "stretch_text", "unit_noise", "units_noise",
    "write_ros2", "write_table",
]


def test_bridge_recorder_still_declares_what_it_did() -> None:
    """Code written against ``bridge.recorder`` before the split runs unchanged: each
    name it declared is still declared, and is what its new home declares (a function,
    never the module of the same name: ``repair``, ``replay``)."""
    recorder = importlib.import_module("bridge.recorder")
    assert set(DECLARED_BEFORE) <= set(recorder.__all__)
    homes = [importlib.import_module(f"bridge.{p}")
             for p in ("archive", "ingest", "export", "analysis")]
    for name in DECLARED_BEFORE:
        value = getattr(recorder, name)
        assert not inspect.ismodule(value), f"bridge.recorder.{name} is a module"
        for home in homes:
            if name in home.__all__:
                assert value is getattr(home, name), f"bridge.recorder.{name}"
    assert sum(name in home.__all__ for home in homes for name in DECLARED_BEFORE) == 47


def _drawn(text: str) -> dict[str, tuple[str | None, tuple[str, ...]]]:
    """A drawn exception tree: each class -> (its parent in the tree, its standard parents)."""
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.strip() == "Gx3Error")
    margin = len(lines[first]) - len(lines[first].lstrip())
    drawn: dict[str, tuple[str | None, tuple[str, ...]]] = {"Gx3Error": (None, ())}
    parents = ["Gx3Error"]
    for line in lines[first + 1 :]:
        m = re.match(r"(?P<indent>(?:│   |    )*)[├└]── (?P<name>\w+)(?: \((?P<std>[^)]*)\))?",
                     line[margin:])
        if m is None:
            break
        depth = len(m.group("indent")) // 4 + 1
        parents[depth:] = [m.group("name")]
        std = tuple(s.strip() for s in m.group("std").split(",")) if m.group("std") else ()
        drawn[m.group("name")] = (parents[depth - 1], std)
    return drawn


def _classes() -> dict[str, tuple[str | None, tuple[str, ...]]]:
    """The exception classes: each -> (its Gx3Error parent, its standard parents)."""
    found: dict[str, tuple[str | None, tuple[str, ...]]] = {}
    for name, cls in inspect.getmembers(bridge.exceptions, inspect.isclass):
        if issubclass(cls, bridge.exceptions.Gx3Error):
            ours = [b.__name__ for b in cls.__bases__
                    if issubclass(b, bridge.exceptions.Gx3Error)]
            std = tuple(b.__name__ for b in cls.__bases__
                        if not issubclass(b, bridge.exceptions.Gx3Error) and b is not Exception)
            found[name] = (ours[0] if ours else None, std)
    return found


@pytest.mark.parametrize("where", ["docs/design/architecture.md", "bridge/exceptions.py"])
def test_the_drawn_exception_tree_is_the_classes(where: str) -> None:
    drawn = _drawn((ROOT / where).read_text(encoding="utf-8"))
    assert len(drawn) >= 20
    assert drawn == _classes()
    assert set(drawn) == set(bridge.exceptions.__all__)
