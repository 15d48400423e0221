"""Why a Zenoh client could not connect: nothing listening, TLS, or the wrong protocol.

Zenoh says only "Unable to connect to any of [...]" whether the router is down, does
not trust this machine's certificate, is not trusted by it, or speaks TLS where the
endpoint says tcp/ (its reasons go to its log). ``why_not`` finds out the way Zenoh
would have: a TCP connection to each endpoint, then for ``tls/`` a TLS handshake with
the configuration's CA, certificate and key. Each step is bounded by ``PROBE_S``.
"""

from __future__ import annotations

import socket
import ssl
from pathlib import Path
from typing import Any

#: How long one step of a check (a connection, a handshake, the router's verdict) may take.
PROBE_S = 3.0
#: OpenSSL's codes for a certificate that is valid but not for the name (or IP address)
#: connected to.
_NAME_MISMATCH = (62, 64)
#: Alerts a TLS server sends when it refuses the client's certificate.
_REFUSED_CERTIFICATE = ("ALERT_UNKNOWN_CA", "ALERT_BAD_CERTIFICATE",
                        "ALERT_CERTIFICATE_UNKNOWN", "ALERT_UNSUPPORTED_CERTIFICATE",
                        "ALERT_CERTIFICATE_EXPIRED", "ALERT_CERTIFICATE_REVOKED",
                        "ALERT_DECRYPT_ERROR", "ALERT_ACCESS_DENIED")
UNREACHABLE = "is the router or peer running and reachable?"


def why_not(endpoint: str, tls: dict[str, Any]) -> str:
    """What stopped a connection to an endpoint, and what to do about it.

    Args:
        endpoint: ``tcp/HOST:PORT`` or ``tls/HOST:PORT``, as Zenoh's configuration has it.
        tls: The configuration's ``transport/link/tls`` settings.

    Returns:
        One line for people.
    """
    proto, _, rest = endpoint.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host, _, port = address.rpartition(":")
    host = host.strip("[]")
    if proto not in ("tcp", "tls") or not host or not port.isdigit():
        return f"no session ({UNREACHABLE})"
    try:
        sock = socket.create_connection((host, int(port)), timeout=PROBE_S)
    except socket.gaierror:
        return f"the name {host!r} does not resolve ({UNREACHABLE})"
    except OSError as exc:
        reason = "nothing listens there" if isinstance(exc, ConnectionRefusedError) \
            else (exc.strerror or "no answer").lower()
        return f"{reason} ({UNREACHABLE})"
    with sock:
        return _tls_problem(sock, host, tls) if proto == "tls" else _tcp_problem(sock, address)


def _tls_problem(sock: socket.socket, host: str, tls: dict[str, Any]) -> str:
    ca, cert, key = (tls.get(k) for k in ("root_ca_certificate", "connect_certificate",
                                         "connect_private_key"))
    mtls = bool(tls.get("enable_mtls"))
    for setting, path in (("root_ca_certificate", ca), ("connect_certificate", cert),
                          ("connect_private_key", key)):
        if path and (mtls or setting == "root_ca_certificate") and not Path(path).is_file():
            return f"transport/link/tls/{setting} {path}: no such file"
    try:
        context = ssl.create_default_context(cafile=ca)
    except ssl.SSLError as exc:
        return f"transport/link/tls/root_ca_certificate {ca}: not a PEM certificate ({exc.reason})"
    context.check_hostname = tls.get("verify_name_on_connect") is not False
    if mtls:
        if not (cert and key):
            return ("enable_mtls is on but connect_certificate and connect_private_key are "
                    "not both set")
        try:
            context.load_cert_chain(cert, key)
        except ssl.SSLError as exc:
            return (f"connect_certificate {cert} and connect_private_key {key} do not go "
                    f"together ({exc.reason}): give this machine's PEM certificate and its key")
    mine = f"this client's certificate {cert}" if mtls else "this client (no certificate)"
    try:
        with context.wrap_socket(sock, server_hostname=host) as link:
            return _verdict(link, mine)
    except ssl.SSLCertVerificationError as exc:
        if exc.verify_code in _NAME_MISMATCH:
            return (f"the router's certificate is not for {host}: connect to the name in it "
                    "(its subjectAltName), or set verify_name_on_connect: false")
        trusted = ca or "the system's CAs"
        return (f"the router's certificate is not trusted ({exc.verify_message}): "
                f"root_ca_certificate ({trusted}) must be the CA that signed it")
    except ssl.SSLError as exc:
        return _alert(exc, mine) or (f"no TLS there ({exc.reason}): the router may listen "
                                     "with tcp/, not tls/")
    except OSError:
        return ("no TLS answer: the router may listen with tcp/ there, not tls/ "
                "(or it dropped the connection)")


def _verdict(link: ssl.SSLSocket, mine: str) -> str:
    """The server's verdict on the client's certificate, after a TLS 1.3 handshake.

    It is still to come after the handshake: an alert, or silence while it waits for
    Zenoh's first message.
    """
    try:
        closed = link.recv(1) == b""
    except ssl.SSLError as exc:
        return _alert(exc, mine) or f"the router ended TLS ({exc.reason})"
    except OSError:  # silence: TLS is fine both ways
        return ("TLS works both ways but the router refused the Zenoh session: is it a "
                "Zenoh router of the same version, and is its configuration valid?")
    return f"the router closed the connection after TLS: it may refuse {mine}" if closed \
        else "the router answered before Zenoh spoke: is it a Zenoh router?"


def _alert(exc: ssl.SSLError, mine: str) -> str | None:
    reason = str(exc.reason or "")
    if reason.endswith("ALERT_CERTIFICATE_REQUIRED"):
        return ("the router asks for a client certificate (mutual TLS): set enable_mtls: "
                "true, connect_certificate and connect_private_key (configs/tls/"
                "client-mtls.json5)")
    if reason.endswith(_REFUSED_CERTIFICATE):
        return (f"the router refuses {mine} ({reason}): it must be signed by the CA the "
                "router trusts, and be valid now")
    return None


def _tcp_problem(sock: socket.socket, address: str) -> str:
    """Something listens but opened no Zenoh session: a TLS listener, or not Zenoh."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname = False
    context.verify_mode = ssl.CERT_NONE
    try:
        with context.wrap_socket(sock):
            speaks_tls = True
    except ssl.SSLError as exc:
        speaks_tls = "ALERT" in str(exc.reason or "")
    except OSError:
        speaks_tls = False
    if speaks_tls:
        return (f"the router expects TLS there: connect to tls/{address} with the fleet's "
                "CA (configs/tls/client.json5)")
    return ("something listens there but opened no Zenoh session: is it a Zenoh router or "
            "peer of the same version?")
