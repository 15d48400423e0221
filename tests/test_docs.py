"""The README and the documentation pages: links that resolve, examples that import only
what the library declares, and a README that stays a front page.

Read statically (no MkDocs, nothing imported from ``bridge``), so it runs in the test
venv in a fraction of a second; ``mkdocs build --strict`` (.ci/run) checks the rest:
anchors, the navigation, the API pages and the generated reference.
"""

from __future__ import annotations

import ast
import re
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
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
