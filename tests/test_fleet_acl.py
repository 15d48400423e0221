"""configs/tls/router-acl.json5 for real: mutual TLS, and each certificate does its job only.

A `gx3 router` process runs the shipped config (its certificate paths and port swapped
for ones made here); a `gx3 bridge` process serves an emulated unit with a bridge's
certificate; the operator, recorder and bridge-role sessions of the test connect with
configs/tls/client-mtls.json5 and their own certificates. Only the bridge may serve or
answer a unit's keys, only the operator may command, the recorder reads. When a
client cannot get in, its one-line error says why.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from bridge.bus.remote import ask_units
from bridge.bus.session import ZenohOptions
from bridge.bus.subscribe import subscribe
from bridge.exceptions import RemoteError, SessionError
from bridge.sim.serve import Simulator
from tests.helpers.processes import GX3, bridge_process
from tests.helpers.units import SLOW
from tests.helpers.waiting import free_port, wait_for
from tests.helpers.zenoh import make_certificates

CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "tls"
ROLES = ("gx3-bridge", "gx3-operator", "gx3-recorder")

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None,
                                reason="needs the openssl command")


def client_certificate(tmp: Path, name: str, ca: str = "ca") -> None:
    """A client's certificate named ``name``: the commands of router-acl.json5."""
    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=tmp, check=True, capture_output=True)
    run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-subj", f"/CN={name}", "-addext", "extendedKeyUsage=clientAuth",
        "-keyout", f"{name}.key", "-out", f"{name}.csr")
    run("x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
        "-CAcreateserial", "-days", "30", "-copy_extensions", "copy", "-out", f"{name}.pem")


def shipped(name: str, tmp: Path, **swaps: str) -> Path:
    """A shipped config with /etc/gx3/tls/ pointing at ``tmp`` and ``swaps`` made."""
    text = (CONFIGS / name).read_text().replace("/etc/gx3/tls/", f"{tmp}/")
    for old, new in swaps.items():
        assert old in text, old
        text = text.replace(old, new)
    path = tmp / f"{Path(name).stem}-{len(list(tmp.glob('*.json5')))}.json5"
    path.write_text(text)
    return path


def client(tmp: Path, port: int, name: str, **swaps: str) -> Path:
    """client-mtls.json5 for the router on ``port``, with ``name``'s certificate."""
    return shipped("client-mtls.json5", tmp, **{
        "ROUTER:7447": f"localhost:{port}", "client.pem": f"{name}.pem",
        "client.key": f"{name}.key", **swaps})


def answers(session: zenoh.Session, key: str) -> list[zenoh.Sample]:
    return [r.ok for r in session.get(key, timeout=10) if r.ok is not None]


@dataclass(frozen=True)
class Fleet:
    tmp: Path
    port: int

    def config(self, name: str) -> Path:
        return client(self.tmp, self.port, name)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Fleet]:
    """The router, and a bridge with --allow-commands serving unit "slow" through it."""
    tmp = tmp_path_factory.mktemp("acl")
    make_certificates(tmp)
    for name in ROLES:
        client_certificate(tmp, name)
    client_certificate(tmp, "stranger", ca="other-ca")
    port = free_port()
    router_cfg = shipped("router-acl.json5", tmp,
                         **{"tls/0.0.0.0:7447": f"tls/127.0.0.1:{port}"})
    router = subprocess.Popen([GX3, "router", "--zenoh-config", str(router_cfg)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert router.stdout is not None and router.stdout.readline().strip() == "READY", \
            router.stderr.read() if router.stderr else ""
        fleet = Fleet(tmp, port)
        with Simulator([SLOW], "pty") as sim, \
                bridge_process(sim.endpoints[0], fleet.config("gx3-bridge"), "--unit", "slow",
                               "--allow-commands"):
            ask_units("gx3", "slow", "info", {}, zenoh_config=fleet.config("gx3-operator"),
                      discovery=60)
            yield fleet
    finally:
        router.send_signal(signal.SIGINT)
        try:
            router.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            router.kill()
            router.communicate()


def test_a_rogue_cannot_take_a_units_commands_and_the_bridge_answers(fleet: Fleet) -> None:
    """A recorder's certificate declares the unit's command queryable (complete, so it
    would be the best match) to answer set-timer with a fake success."""
    heard: list[str] = []

    def fake(query: zenoh.Query) -> None:
        heard.append(str(query.key_expr))
        query.reply("gx3/slow/command", json.dumps({"timer": 1000, "rogue": True}))

    with zenoh.open(zenoh.Config.from_file(str(fleet.config("gx3-recorder")))) as rogue:
        queryable = rogue.declare_queryable("gx3/slow/command", fake, complete=True)
        # The router handles the rogue's messages in order: once the rogue has its info
        # answer, its declaration has been taken in or dropped.
        assert answers(rogue, "gx3/slow/info")
        results = ask_units("gx3", "slow", "set_timer", {"value": 1000},
                            zenoh_config=fleet.config("gx3-operator"))
        queryable.undeclare()
    assert heard == [], "the rogue received the operator's command"
    assert len(results) == 1, results
    unit, ok, result = results[0]
    assert (unit, ok, "rogue" in result) == ("slow", True, False)
    assert result["timer"] >= 1000


def test_the_recorder_reads_and_asks_info_but_cannot_command_or_publish(fleet: Fleet) -> None:
    recorder = fleet.config("gx3-recorder")
    with subscribe("gx3/slow/imu", zenoh_config=recorder, history=10) as samples:
        sample = samples.get(timeout=30)
    assert sample is not None and sample.unit == "slow"
    info = ask_units("gx3", "slow", "info", {}, zenoh_config=recorder)
    assert [(unit, ok, result["serial"]) for unit, ok, result in info] == \
        [("slow", True, "SLOW0001")]
    with pytest.raises(RemoteError) as refused:
        ask_units("gx3", "slow", "set_timer", {"value": 7}, zenoh_config=recorder, timeout=2)
    assert "slow is alive but did not answer on gx3/slow/command" in str(refused.value)
    assert "access control" in str(refused.value) and "operator" in str(refused.value)

    # What reaches a bridge does so in the order the recorder sent it: when its info
    # query arrives, a command or a put sent before it would already have.
    got: list[str] = []

    with zenoh.open(zenoh.Config.from_file(str(fleet.config("gx3-bridge")))) as bridge, \
            zenoh.open(zenoh.Config.from_file(str(recorder))) as rogue:
        # (undeclared when the session closes)
        bridge.declare_subscriber("gx3/probe/**", lambda s: got.append("put"))
        bridge.declare_queryable("gx3/probe/command", lambda q: got.append("command"))
        bridge.declare_queryable("gx3/probe/info", lambda q: q.reply("gx3/probe/info", b"p"))
        wait_for(lambda: bool(answers(rogue, "gx3/probe/info")), what="the probe's queryable")
        rogue.put("gx3/probe/imu", b"fake sample")
        rogue.get("gx3/probe/command", payload='{"action": "reset"}', timeout=0.5)
        answered = answers(rogue, "gx3/probe/info")
    assert answered
    assert got == [], f"the recorder's {got} reached the bridge"


def test_a_fleet_command_names_each_alive_bridge_that_did_not_answer(fleet: Fleet) -> None:
    with zenoh.open(zenoh.Config.from_file(str(fleet.config("gx3-bridge")))) as mute:
        mute.declare_queryable("gx3/mute/command", lambda query: None)  # drops every query
        token = mute.liveliness().declare_token("gx3/mute/alive")
        operator = fleet.config("gx3-operator")
        wait_for(lambda: "mute" in {u for u, _, _ in ask_units(
            "gx3", "*", "info", {}, zenoh_config=operator, timeout=2)}, what="mute's token")
        results = ask_units("gx3", "*", "stationary_test", {}, zenoh_config=operator, timeout=2)
        token.undeclare()
    assert [(unit, ok) for unit, ok, _ in results] == [("mute", False), ("slow", True)]
    assert results[0][2] == {"error": "alive but did not answer on gx3/*/command within 2 s"}


def one_line(options: ZenohOptions) -> str:
    with pytest.raises(SessionError) as caught:
        options.open().close()
    message = str(caught.value)
    assert "\n" not in message, message
    return message


def test_a_client_that_cannot_get_in_is_told_why(fleet: Fleet) -> None:
    tmp, port = fleet.tmp, fleet.port
    wrong_ca = client(tmp, port, "gx3-operator", **{"/ca.pem": "/other-ca.pem"})
    assert "router's certificate is not trusted" in one_line(ZenohOptions(wrong_ca))
    assert "must be the CA that signed it" in one_line(ZenohOptions(wrong_ca))
    stranger = client(tmp, port, "stranger")
    assert f"the router refuses this client's certificate {tmp}/stranger.pem" in \
        one_line(ZenohOptions(stranger))
    no_mtls = client(tmp, port, "gx3-operator", **{"enable_mtls: true": "enable_mtls: false"})
    assert "the router asks for a client certificate (mutual TLS)" in \
        one_line(ZenohOptions(no_mtls))
    by_address = client(tmp, port, "gx3-operator", **{"tls/localhost": "tls/127.0.0.1"})
    assert "the router's certificate is not for 127.0.0.1" in \
        one_line(ZenohOptions(by_address))
    plain = client(tmp, port, "gx3-operator", **{"tls/localhost": "tcp/localhost"})
    assert f"the router expects TLS there: connect to tls/localhost:{port}" in \
        one_line(ZenohOptions(plain))
    assert one_line(ZenohOptions(fleet.config("gx3-operator"), [f"tls/localhost:{free_port()}"])) \
        .endswith("nothing listens there (is the router or peer running and reachable?)")
    done = subprocess.run([GX3, "info", "--unit", "slow", "--zenoh-config", str(wrong_ca)],
                          capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 1
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "router's certificate is not trusted" in done.stderr
