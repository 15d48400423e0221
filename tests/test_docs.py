"""The README and the documentation pages: links that resolve, examples that import only
what the library declares, a README that stays a front page, a demo shown as `gx3 demo`
runs it, and the getting-started page's commands, run as a reader runs them.

The pages are read statically (no MkDocs; of ``bridge``, only the demo command's
defaults), in a fraction of a second, but for the commands run; ``mkdocs build
--strict`` (.ci/run) checks the rest: anchors, the navigation, the API pages and the
generated reference.
"""

from __future__ import annotations

import ast
import contextlib
import inspect
import json
import os
import re
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from typing import IO

import pytest

from tests.helpers.waiting import free_port, wait_for

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "getting-started.md"
PAGES = sorted((ROOT / "docs").rglob("*.md"))
DOCUMENTS = [README, ROOT / "CHANGELOG.md", *PAGES]
README_LIMIT = 10 * 1024

_FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
_INLINE_CODE = re.compile(r"(`+)(?:(?!\1).)+?\1")
_LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)")
_HTML_LINK = re.compile(r"""<(?:a|img)\b[^>]*?\b(?:href|src)=["']([^"']+)["']""")
_SNIPPET = re.compile(r"""^\s*-{2}8<-{2}\s+["']([^"']+)["']""")
_PYTHON = {"python", "py", "python3", "pycon"}


def _name(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _blocks(text: str) -> tuple[list[str], list[tuple[str, str]]]:
    """The text's lines outside fenced code (code blocks blanked), and each fenced block
    as (its language, its code)."""
    prose: list[str] = []
    blocks: list[tuple[str, str]] = []
    fence: tuple[str, str, str] | None = None  # marker, language, indent
    code: list[str] = []
    for line in text.splitlines():
        if fence is None:
            opened = _FENCE.match(line)
            if opened:
                fence = (opened.group(2), opened.group(3).lower(), opened.group(1))
                code = []
                prose.append("")
            else:
                prose.append(line)
            continue
        marker, language, indent = fence
        if line.strip().startswith(marker[0] * len(marker)) and not line.strip().strip(
                marker[0]):
            blocks.append((language, textwrap.dedent("\n".join(code))))
            fence = None
        else:
            code.append(line[len(indent):] if line.startswith(indent) else line)
        prose.append("")
    return prose, blocks


def _links(text: str) -> Iterator[str]:
    """Every link target in Markdown prose: inline links and images, reference
    definitions and HTML links; none from code."""
    prose, _ = _blocks(text)
    for line in prose:
        line = _INLINE_CODE.sub("", line)
        yield from _LINK.findall(line)
        yield from _HTML_LINK.findall(line)
        reference = _REFERENCE.match(line)
        if reference:
            yield reference.group(1)


def _relative(target: str) -> str | None:
    """The file part of a link that points into the repository, or None for a link
    elsewhere (a URL, an e-mail address) or within the page (an anchor)."""
    if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith(("#", "//")):
        return None
    path = target.split("#", 1)[0].split("?", 1)[0]
    return path or None


def _broken_links(document: Path) -> list[str]:
    broken = []
    for target in _links(document.read_text(encoding="utf-8")):
        path = _relative(target)
        if path is None:
            continue
        if path.startswith("/"):
            broken.append(f"{target} (absolute: link relative to the page)")
            continue
        resolved = (document.parent / path).resolve()
        if not resolved.is_relative_to(ROOT):
            broken.append(f"{target} (outside the repository)")
        elif not resolved.exists():
            broken.append(f"{target} (no such file)")
    return broken


@pytest.mark.parametrize("document", DOCUMENTS, ids=_name)
def test_every_relative_link_resolves_to_a_file_in_the_repository(document: Path) -> None:
    broken = _broken_links(document)
    assert not broken, f"{_name(document)}: " + "; ".join(broken)


@pytest.mark.parametrize("document", DOCUMENTS, ids=_name)
def test_every_included_file_exists(document: Path) -> None:
    """Snippet includes (``--8<-- "path"``) are taken from the repository's root."""
    included = [m.group(1) for line in document.read_text(encoding="utf-8").splitlines()
                if (m := _SNIPPET.match(line))]
    missing = [path for path in included if not (ROOT / path).is_file()]
    assert not missing, f"{_name(document)} includes {missing}, not in the repository"


def _declared(module: str) -> list[str] | None:
    """The names a package of ``bridge`` declares in ``__all__``, read from its
    ``__init__.py`` without importing it; None where it declares none."""
    init = ROOT.joinpath(*module.split("."), "__init__.py")
    names: list[str] | None = None
    for node in ast.parse(init.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            if not any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
                continue
            assert node.value is not None
            value = ast.literal_eval(node.value)
            names = [*(names if isinstance(node, ast.AugAssign) and names else []), *value]
    return names


def _is_package(module: str) -> bool:
    return ROOT.joinpath(*module.split("."), "__init__.py").is_file()


def _undeclared(code: str) -> list[str]:
    """Each import from ``bridge`` in an example that a user of the library could not
    rely on: a name its package does not declare, or a module that is not a package."""
    if any(line.lstrip().startswith(">>>") for line in code.splitlines()):
        code = "\n".join(line.lstrip()[4:] for line in code.splitlines()
                         if line.lstrip().startswith((">>>", "...")))
    problems = []
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.ImportFrom) and node.module and (
                node.module == "bridge" or node.module.startswith("bridge.")):
            if not _is_package(node.module):
                problems.append(f"from {node.module} import ...: {node.module} is a module, "
                                "not a package; import from its package")
                continue
            declared = _declared(node.module) or []
            problems += [f"from {node.module} import {alias.name}: not in "
                         f"{node.module}.__all__" for alias in node.names
                         if alias.name not in declared]
        elif isinstance(node, ast.Import):
            problems += [f"import {alias.name}: {alias.name} is a module, not a package"
                         for alias in node.names
                         if alias.name.startswith("bridge.") and not _is_package(alias.name)]
    return problems


def _examples(document: Path) -> list[str]:
    """The Python code blocks of a document that import from ``bridge``."""
    _, blocks = _blocks(document.read_text(encoding="utf-8"))
    return [code for language, code in blocks if language in _PYTHON
            and re.search(r"^\s*(?:>>>\s*)?(?:from|import)\s+bridge\b", code, re.M)]


@pytest.mark.parametrize("document", DOCUMENTS, ids=_name)
def test_examples_import_only_names_their_package_declares(document: Path) -> None:
    problems = []
    for code in _examples(document):
        try:
            problems += _undeclared(code)
        except SyntaxError as error:
            problems.append(f"an example that is not Python: {error}")
    assert not problems, f"{_name(document)}: " + "; ".join(problems)


def test_the_checks_see_links_and_examples() -> None:
    """The checks above pass trivially if they find nothing: they find what is there."""
    links = [t for d in DOCUMENTS for t in _links(d.read_text(encoding="utf-8"))]
    assert sum(_relative(t) is not None for t in links) >= 50
    assert sum(len(_examples(d)) for d in DOCUMENTS) >= 3
    text = "[a](x.md) `[b](y.md)`\n```python\nfrom bridge.sim.serve import Simulator\n```\n"
    assert list(_links(text)) == ["x.md"]
    (code,) = (code for _, code in _blocks(text)[1])
    assert _undeclared(code) == ["from bridge.sim.serve import ...: bridge.sim.serve is a "
                                 "module, not a package; import from its package"]
    assert _undeclared("from bridge import nothing_declared") == [
        "from bridge import nothing_declared: not in bridge.__all__"]


def test_readme_is_a_front_page_of_at_most_10_kb() -> None:
    size = len(README.read_bytes())
    assert size <= README_LIMIT, (f"README.md is {size:,} bytes; a front page is at most "
                                  f"{README_LIMIT:,}: move the detail into docs/")


def test_the_readmes_first_screen_says_what_it_is_and_what_to_try() -> None:
    """A newcomer's first screen (24 lines): what the product is and the one command to
    try, which ends in the demo with the environment active (so the demo's own
    suggestions, bare `gx3` and `rerun`, run in that shell)."""
    first = README.read_text().splitlines()[:24]
    assert "3DM-GX3" in " ".join(first[:4])
    (command,) = [line for line in first if line.startswith("python3 -m venv")]
    assert ". .venv/bin/activate && gx3 demo" in command


#: How Rerun 0.41 serves its web viewer on loopback, where there is no display.
SERVE_WEB = "rerun --serve-web --bind 127.0.0.1 --port 9876 --web-viewer-port 9090"
WEB_VIEWER = "http://127.0.0.1:9090/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A9876%2Fproxy"


@pytest.mark.parametrize("document", [README, GETTING_STARTED], ids=_name)
def test_the_demo_shown_is_what_gx3_demo_does(document: Path) -> None:
    """The text's fleet and duration are the demo's defaults, the run shown is ``gx3 demo``
    with them (a unit per line), and a reader with no display is pointed to the web
    viewer, as the demo itself points."""
    from bridge.cli.demo import demo

    defaults = {name: param.default
                for name, param in inspect.signature(demo).parameters.items()}
    words = {1: "one", 2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}
    text = " ".join(document.read_text().split())
    said = re.search(r"(?:For (\d+) seconds (\w+) emulated units|(\w+) emulated units stream "
                     r"[^.;]* for (\d+) seconds)", text, re.I)
    assert said, "the page does not say how many units the demo runs, and for how long"
    seconds, units = (said[1], said[2]) if said[1] else (said[4], said[3])
    assert (float(seconds), units.lower()) == (defaults["duration"], words[defaults["units"]])
    shown = document.read_text().split("\n$ gx3 demo", 1)[1].split("```", 1)[0]
    assert shown.startswith("\n"), "the run shown is not plain gx3 demo"
    assert len(re.findall(r"^imu\d+ ", shown, re.M)) == defaults["units"]
    assert SERVE_WEB in text and WEB_VIEWER in text


# -- getting started, run --------------------------------------------------------------------

def _shell_blocks(title: str) -> list[str]:
    """The ``sh`` blocks of the getting-started section ``title``, in order."""
    section = GETTING_STARTED.read_text().split(f"\n## {title}\n", 1)[1].split("\n## ")[0]
    return [code for language, code in _blocks(section)[1] if language == "sh"]


def _reader(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A reader's checkout, as far as the steps see it: this test's virtual environment
    as its .venv, configs/loopback as shipped but on a free port (another test may hold
    7447), and a temporary folder of its own for mktemp; and the environment."""
    checkout = tmp_path / "checkout"
    (checkout / "configs" / "loopback").mkdir(parents=True)
    (checkout / ".venv").symlink_to(Path(sys.prefix))
    port = free_port()
    for name in ("listen", "connect"):
        text = (ROOT / "configs" / "loopback" / f"{name}.json5").read_text()
        (checkout / "configs" / "loopback" / f"{name}.json5").write_text(
            text.replace("127.0.0.1:7447", f"127.0.0.1:{port}"))
    (tmp_path / "tmp").mkdir()
    return checkout, {**os.environ, "TMPDIR": str(tmp_path / "tmp"), "COLUMNS": "200"}


def _run(script: str, cwd: Path, env: dict[str, str], stderr: IO[str]
         ) -> subprocess.Popen[str]:
    """``script`` in bash, in a session of its own (what it leaves running is stopped by
    the caller, by its group)."""
    return subprocess.Popen(["bash", "-c", script], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=stderr, start_new_session=True)


def _stop(proc: subprocess.Popen[str]) -> None:
    """Stop whatever ``_run``'s script left running (its background jobs)."""
    with contextlib.suppress(ProcessLookupError):  # nothing was left
        os.killpg(proc.pid, signal.SIGTERM)
    proc.wait(timeout=60)


def test_the_bytes_by_hand_run_as_the_page_gives_them(tmp_path: Path) -> None:
    """Steps 1 to 6, from a checkout: nothing is left in it, the capture decodes, and
    Ctrl-C (to the pipeline's process group, as a terminal sends it) ends the live decode
    quietly: the summary so far, no traceback, no error, exit 130."""
    checkout, env = _reader(tmp_path)
    install, sim, capture, decode, live, clean = _shell_blocks("The bytes on the line, by hand")
    setup = "\n".join(line for line in install.splitlines() if "pip install" not in line)
    log, errors = tmp_path / "stderr.txt", tmp_path / "live.txt"
    with log.open("w") as stderr:
        first = _run("set -e\n" + "\n".join([setup, sim, capture, decode]), checkout, env,
                     stderr)
    try:
        out, _ = first.communicate(timeout=180)
        assert first.returncode == 0, (out, log.read_text())
        scratch, endpoint, record = out.splitlines()
        (summary,) = [line for line in log.read_text().splitlines()
                      if line.startswith("records:")]
        env["scratch"] = scratch
        assert Path(scratch).is_relative_to(tmp_path / "tmp"), scratch
        assert endpoint.startswith("socket://127.0.0.1:")
        assert re.fullmatch(r"records: 0xC8×\d+; checksum failures: \d+; implausible: 0; "
                            r"bytes skipped: \d+ of [\d,]+; resyncs: [01]", summary), summary
        assert json.loads(record)["command"] == 0xC8

        with errors.open("w") as stderr:
            pipeline = _run(live, checkout, env, stderr)
        assert pipeline.stdout is not None
        for _ in range(5):
            assert json.loads(pipeline.stdout.readline())["command"] == 0xC8
        os.killpg(pipeline.pid, signal.SIGINT)
        pipeline.communicate(timeout=60)
        said = errors.read_text()
        assert pipeline.returncode == 130, said
        assert "Traceback" not in said and "error" not in said, said
        assert said.startswith("records: 0xC8×") and said.count("\n") == 1, said

        done = subprocess.run(["bash", "-c", clean], cwd=checkout, env=env, text=True,
                              capture_output=True, timeout=60, check=False)
        assert done.returncode == 0 and not Path(scratch).exists(), done.stderr
    finally:
        _stop(first)
    assert sorted(p.name for p in checkout.iterdir()) == [".venv", "configs"]


def test_a_unit_its_bridge_and_the_recorder_run_as_the_page_gives_them(
        tmp_path: Path) -> None:
    """Each its own process on configs/loopback, then gx3 allan on the archive; the
    scratch folder the first section's, the recorder for 10 s instead of a minute, and
    started once the bridge streams (one shell, fed the steps as a reader types them), so
    that a slow start cannot leave it nothing to record."""
    checkout, env = _reader(tmp_path)
    sim, bridge, record, allan, stop = _shell_blocks(
        "A unit, its bridge and the recorder, by hand")
    setup = _shell_blocks("The bytes on the line, by hand")[0].splitlines()[-1]
    assert setup.startswith("scratch=$(mktemp -d)")
    log = tmp_path / "stderr.txt"
    with log.open("w") as stderr:
        shell = subprocess.Popen(["bash", "-s"], cwd=checkout, env=env, text=True,
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 stderr=stderr, start_new_session=True)
    assert shell.stdin is not None and shell.stdout is not None
    try:
        shell.stdin.write("\n".join(["set -e", setup, sim, bridge, ""]))
        shell.stdin.flush()
        scratch = Path(shell.stdout.readline().strip())
        bridge_log = scratch / "bridge.log"
        wait_for(lambda: bridge_log.exists() and "bring_up" in bridge_log.read_text(),
                 what="the bridge to bring its unit up")
        shell.stdin.write("\n".join([record.replace("--duration 60", "--duration 10"),
                                     allan, stop.replace('rm -r "$scratch"', ""), ""]))
        shell.stdin.close()
        shell.wait(timeout=300)
    finally:
        _stop(shell)
    said = log.read_text()
    assert shell.returncode == 0, said
    assert re.search(r"^wrote \S+/imu\.yaml and \S+/allan\.png: unit still, accelerometer "
                     r"N ", said, re.M), said
    bridge = bridge_log.read_text()
    assert "bring_up 3DM-GX3-25" in bridge and "still: " in bridge, bridge
    assert sorted(p.name for p in checkout.iterdir()) == [".venv", "configs"]
