"""Files the project ships for other tools and languages stay true to the code."""

from __future__ import annotations

import json
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


@pytest.mark.parametrize("path", sorted((ROOT / "configs").glob("*.json5")), ids=lambda p: p.name)
def test_zenoh_configs_open_a_real_session(path: Path) -> None:
    config = zenoh.Config.from_file(str(path))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as session:
        assert str(session.zid())
