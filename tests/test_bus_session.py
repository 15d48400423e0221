"""Sessions from the shipped configs and flags, for real on loopback; one-line errors."""

from __future__ import annotations

import json
import re
import shutil
import threading
from pathlib import Path

import pytest
import zenoh

from bridge.bus.session import ZenohOptions, open_session
from bridge.exceptions import SessionError
from tests.helpers.waiting import free_port
from tests.helpers.zenoh import make_certificates

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def free_endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


def exchange(sender: zenoh.Session, receiver: zenoh.Session) -> None:
    """A put from ``sender`` reaches ``receiver`` (retried until routes are up)."""
    got = threading.Event()
    sub = receiver.declare_subscriber("gx3/test/ping", lambda s: got.set())
    for _ in range(100):
        sender.put("gx3/test/ping", b"x")
        if got.wait(0.1):
            break
    sub.undeclare()
    assert got.is_set(), "nothing arrived"


def test_loopback_config_with_flags_overriding_its_endpoints() -> None:
    a_ep, b_ep = free_endpoint(), free_endpoint()
    config = CONFIGS / "loopback" / "listen.json5"
    with open_session(config, listen=[a_ep]) as a, \
            open_session(config, listen=[b_ep], connect=[a_ep]) as b:
        assert ZenohOptions(config, listen=[a_ep]).config().get_json("listen/endpoints") \
            == f'["{a_ep}"]'
        exchange(a, b)
        exchange(b, a)


def test_fleet_clients_reach_each_other_through_the_router() -> None:
    ep = free_endpoint()
    client = CONFIGS / "fleet" / "client.json5"
    assert ZenohOptions(client).config().get_json("connect/endpoints") == '["tcp/ROUTER:7447"]'
    with open_session(CONFIGS / "fleet" / "router.json5", listen=[ep]) as router, \
            open_session(client, connect=[ep]) as bridge_side, \
            open_session(client, connect=[ep]) as recorder_side:
        assert [str(z) for z in bridge_side.info.routers_zid()] == [str(router.zid())]
        exchange(bridge_side, recorder_side)


def with_certificates(path: Path, tmp: Path, endpoint: str, ca: str = "ca.pem") -> zenoh.Config:
    """A shipped TLS config with its /etc/gx3/tls/ files swapped for ``tmp``'s."""
    config = ZenohOptions(path).config()
    text = path.read_text()
    for key, name in (("listen_certificate", "router.pem"), ("listen_private_key", "router.key"),
                      ("root_ca_certificate", ca)):
        if key in text:
            config.insert_json5(f"transport/link/tls/{key}", json.dumps(str(tmp / name)))
    side = "listen" if "router" in path.name else "connect"
    config.insert_json5(f"{side}/endpoints", json.dumps([endpoint]))
    return config


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_tls_configs_connect_and_refuse_an_untrusted_router(tmp_path: Path) -> None:
    make_certificates(tmp_path)
    endpoint = free_endpoint().replace("tcp/127.0.0.1", "tls/localhost")
    tls = CONFIGS / "tls"
    with zenoh.open(with_certificates(tls / "router.json5", tmp_path, endpoint)) as router, \
            zenoh.open(with_certificates(tls / "client.json5", tmp_path, endpoint)) as a, \
            zenoh.open(with_certificates(tls / "client.json5", tmp_path, endpoint)) as b:
        assert [str(z) for z in a.info.routers_zid()] == [str(router.zid())]
        exchange(a, b)
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            zenoh.open(with_certificates(tls / "client.json5", tmp_path, endpoint,
                                         ca="other-ca.pem"))


def one_line_error(options: ZenohOptions) -> str:
    with pytest.raises(SessionError) as caught:
        options.open().close()
    message = str(caught.value)
    assert "\n" not in message and not re.search(r"\.rs:\d", message), message
    return message


def test_bad_files_and_flags_give_one_line_errors(tmp_path: Path) -> None:
    missing = tmp_path / "nope.json5"
    assert one_line_error(ZenohOptions(missing)) == f"zenoh config {missing}: no such file"
    syntax = tmp_path / "syntax.json5"
    syntax.write_text("{\n  mode: peer,\n}\n")
    assert one_line_error(ZenohOptions(syntax)) == (
        f"zenoh config {syntax}: expected array, boolean, null, number, object, or string "
        "(line 2, column 9)")
    unknown = tmp_path / "unknown.json5"
    unknown.write_text('{ modee: "peer" }')
    assert one_line_error(ZenohOptions(unknown)).startswith(
        f"zenoh config {unknown}: unknown field `modee`, expected one of `id`")
    assert one_line_error(ZenohOptions(mode="pear")) == \
        "--mode 'pear': use one of peer, client, router"
    assert one_line_error(ZenohOptions(connect=["127.0.0.1:7447"])).startswith(
        "--connect 127.0.0.1:7447: Endpoints must be of the form <protocol>/<address>")
    lonely = one_line_error(ZenohOptions(mode="client", connect=[free_endpoint()],
                                         multicast_scouting=False))
    assert lonely.startswith("zenoh session: Unable to connect to any of") and \
        lonely.endswith("(is the router or peer running and reachable?)")
