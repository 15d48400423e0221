"""Files the project ships for other tools and languages stay true to the code."""

from __future__ import annotations

import json
import os
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from bridge.protocol.docs import reply_schemas
from bridge.protocol.table import REPLIES

ROOT = Path(__file__).resolve().parent.parent


def test_reply_schemas_file_matches_the_command_table() -> None:
    shipped = json.loads((ROOT / "schemas" / "replies.json").read_text())
    assert shipped == reply_schemas(), "regenerate with: gx3 commands --json > schemas/replies.json"
    assert {r["code"]: r["length"] for r in shipped["replies"]} == {
        code: spec.length for code, spec in REPLIES.items()}


@pytest.mark.parametrize("path", [*sorted((ROOT / "configs").glob("*.json5")),
                                  ROOT / "configs/systemd/zenoh.json5"],
                         ids=lambda p: str(p.relative_to(ROOT / "configs")))
def test_zenoh_configs_open_a_real_session(path: Path) -> None:
    config = zenoh.Config.from_file(str(path))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as session:
        assert str(session.zid())


# --- the fleet install: configs/install.sh, the systemd units, the fleet guide's steps -------

CONFIGS = ROOT / "configs"
INSTALL = CONFIGS / "install.sh"
UNITS = sorted((CONFIGS / "systemd").glob("*.service"))


def _unit_settings(path: Path) -> dict[str, list[str]]:
    """Each key of a unit file and its values, continuation lines joined."""
    text = re.sub(r"\\\n\s*", "", path.read_text())
    settings: dict[str, list[str]] = {}
    for line in text.splitlines():
        if "=" in line and not line.startswith(("#", "[")):
            key, value = line.split("=", 1)
            settings.setdefault(key.strip(), []).append(value.strip())
    return settings


def _system(root: Path) -> Path:
    """A system tree with the files useradd needs and no gx3 user yet."""
    (root / "etc").mkdir(parents=True)
    for name, text in (("passwd", "root:x:0:0:root:/root:/bin/bash\n"),
                       ("group", "root:x:0:\ndialout:x:20:\n"),
                       ("shadow", "root:*:19000:0:99999:7:::\n"),
                       ("gshadow", "root:*::\ndialout:*::\n")):
        (root / "etc" / name).write_text(text)
    return root


def _install(root: Path, *args: str, env: dict[str, str] | None = None
             ) -> subprocess.CompletedProcess[str]:
    if not shutil.which("useradd", path=os.environ.get("PATH", "") + ":/usr/sbin:/sbin"):
        pytest.skip("useradd is not installed here (Debian: package passwd)")
    return subprocess.run([str(INSTALL), "--root", str(root), *args], capture_output=True,
                          text=True, timeout=300, check=False, env={**os.environ, **(env or {})})


def test_install_script_makes_the_user_folders_and_files(tmp_path: Path) -> None:
    root = _system(tmp_path / "root")
    done = _install(root, "--no-venv")
    assert done.returncode == 0, done.stderr
    users = {line.split(":")[0]: line.split(":") for line in
             (root / "etc/passwd").read_text().splitlines()}
    groups = {line.split(":")[0]: line.split(":") for line in
              (root / "etc/group").read_text().splitlines()}
    gx3 = users["gx3"]
    assert int(gx3[2]) < 1000, "a system user"
    assert gx3[5:] == ["/var/lib/gx3", "/usr/sbin/nologin"]
    assert "gx3" in groups["dialout"][3].split(","), "gx3 may open serial ports"
    assert groups["gx3"][2] == gx3[3]
    lib = root / "var/lib/gx3"
    assert stat.S_IMODE(lib.stat().st_mode) == 0o750
    if os.getuid() == 0:
        assert (lib.stat().st_uid, lib.stat().st_gid) == (int(gx3[2]), int(gx3[3]))
    installed = {
        "etc/gx3/zenoh.json5": "systemd/zenoh.json5",
        "etc/gx3/imu.env.example": "systemd/imu.env.example",
        "etc/udev/rules.d/99-gx3.rules": "udev/99-gx3.rules",
        **{f"etc/systemd/system/{u.name}": f"systemd/{u.name}" for u in UNITS}}
    for path, source in installed.items():
        assert (root / path).read_bytes() == (CONFIGS / source).read_bytes(), path
    # run again (an upgrade): the operator's files stay, the user is not added twice
    (root / "etc/gx3/zenoh.json5").write_text("{ mode: 'client' }")
    again = _install(root, "--no-venv")
    assert again.returncode == 0, again.stderr
    assert (root / "etc/gx3/zenoh.json5").read_text() == "{ mode: 'client' }"
    assert (root / "etc/passwd").read_text().count("\ngx3:") == 1
    assert groups["dialout"] == (root / "etc/group").read_text().splitlines()[1].split(":")


def test_install_script_refuses_a_root_without_a_system(tmp_path: Path) -> None:
    done = _install(tmp_path, "--no-venv")
    assert done.returncode == 2
    assert done.stderr.startswith("error: --root ") and len(done.stderr.splitlines()) == 1


def test_units_pass_systemd_analyze_verify(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    system_units = Path("/usr/lib/systemd/system")
    if analyze is None or not (system_units / "sysinit.target").exists():
        pytest.skip("systemd-analyze (Debian: package systemd) is not installed here")
    root = _system(tmp_path / "root")
    assert _install(root, "--no-venv").returncode == 0
    shutil.copytree(system_units, root / "usr/lib/systemd/system", symlinks=True)
    gx3 = root / "opt/gx3/bin/gx3"
    gx3.parent.mkdir(parents=True)
    installed = shutil.which("gx3", path=str(Path(sys.executable).parent))
    assert installed, "the gx3 console script is not installed next to this interpreter"
    shutil.copy2(installed, gx3)
    done = subprocess.run([analyze, f"--root={root}", "verify", "gx3-bridge@imu1.service",
                           "gx3-record.service"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 0 and done.stderr == "", done.stderr


def test_install_script_puts_gx3_from_a_wheel_in_a_venv(tmp_path: Path) -> None:
    """The pip step, offline: the checkout's own wheel without its dependencies."""
    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source)
    shutil.copytree(ROOT / "bridge", source / "bridge",
                    ignore=shutil.ignore_patterns("__pycache__"))
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                            "--no-build-isolation", "-w", str(tmp_path / "dist"), str(source)],
                           capture_output=True, text=True, timeout=300, check=False)
    if built.returncode != 0:
        pytest.skip("no wheel can be built offline here (setuptools without bdist_wheel)")
    (wheel,) = (tmp_path / "dist").glob("gx3_bridge-*.whl")
    root = _system(tmp_path / "root")
    done = _install(root, str(wheel), env={"PIP_NO_INDEX": "1", "PIP_NO_DEPS": "1"})
    assert done.returncode == 0, done.stderr
    gx3 = root / "opt/gx3/bin/gx3"
    assert os.access(gx3, os.X_OK)
    assert gx3.read_text().startswith(f"#!{root}/opt/gx3/bin/python")
    assert "bridge.cli" in gx3.read_text()


def test_every_variable_the_units_document_is_used() -> None:
    for unit in UNITS:
        documented = set(re.findall(r"^#\s+([A-Z][A-Z_]+)\s{2,}", unit.read_text(), re.M))
        settings = _unit_settings(unit)
        (command,) = settings["ExecStart"]
        used = set(re.findall(r"\$\{?(\w+)\}?", command))
        defaults = {pair.split("=")[0] for pair in " ".join(settings["Environment"]).split()}
        assert documented and used == documented == defaults, unit.name
    example = (CONFIGS / "systemd/imu.env.example").read_text()
    bridge_unit = _unit_settings(CONFIGS / "systemd/gx3-bridge@.service")
    assert set(re.findall(r"^#(\w+)=", example, re.M)) == {
        pair.split("=")[0] for pair in " ".join(bridge_unit["Environment"]).split()}


def _fleet_section() -> str:
    guide = (ROOT / "docs/guides/fleet.md").read_text()
    return guide.split("## Running a real fleet")[1].split("\n## ")[0]


def test_the_fleet_guide_steps_match_the_files(tmp_path: Path) -> None:
    section = _fleet_section()
    for path in set(re.findall(r"configs/[\w./@*-]+\w", section)):
        assert list(ROOT.glob(path)), f"the fleet guide names {path}, which is not in the checkout"
    root = _system(tmp_path / "root")
    assert _install(root, "--no-venv").returncode == 0
    for path in set(re.findall(r"(/(?:etc|var/lib|opt)/gx3[\w./-]*|/etc/udev/[\w./-]+)",
                               section)):
        if "imu1" in path or "imu3" in path or "record.env" in path:
            continue  # the operator's own files
        if path.startswith("/opt/gx3"):
            continue  # the venv (the pip step)
        assert (root / path.lstrip("/")).exists(), f"the fleet guide names {path}; not installed"
    for name in re.findall(r"systemctl enable --now ([\w@ -]+)", section)[0].split():
        template = re.sub(r"@.*", "@", name)
        assert (root / "etc/systemd/system" / f"{template}.service").exists(), name
    shown = re.search(r"^/opt/gx3/bin/gx3 bridge .*$", section, re.M)
    assert shown is not None
    (command,) = _unit_settings(CONFIGS / "systemd/gx3-bridge@.service")["ExecStart"]
    assert shown.group(0) == command.replace("%i", "imu1")


def test_git_leaves_out_what_the_demo_writes_in_a_checkout() -> None:
    """`gx3 demo` run in a clone writes gx3-demo/ (gx3-demo-2/ the next time): logs,
    Zenoh configurations, the archive; none of it shows as a change to commit."""
    written = ["gx3-demo/imu1.log", "gx3-demo/zenoh-bridges.json5", "gx3-demo/demo.mcap",
               "gx3-demo-2/zenoh-recorder.json5"]
    done = subprocess.run(["git", "check-ignore", "--no-index", *written], cwd=ROOT,
                          capture_output=True, text=True, check=False)
    assert done.stdout.split() == written, done.stderr
