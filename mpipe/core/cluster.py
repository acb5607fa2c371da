"""Reaching a Dask scheduler, or one clear line saying why it cannot be used.

Dask's client, given a wrong address, fails badly: a malformed address raises a bare
``ValueError`` from deep inside, an address where an HTTP server listens (the dashboard's
port 8787 instead of the scheduler's 8786) makes it wait for a greeting that never comes
(minutes, and Ctrl-C does not end it) or read the first bytes of an HTTP reply as a frame
length ("Unable to allocate 3.07 EiB": ``HTTP/1.1`` read as a 64-bit integer), and an
address nobody answers costs the client's whole retry budget. Before any client is made,
:func:`check_scheduler` therefore parses the address, opens a plain TCP connection with a
short timeout and reads the first bytes the far end sends: a Dask scheduler greets every
connection at once with its handshake, a frame whose first eight bytes are its small byte
count. Only the standard library is used here, so this also runs where Dask is missing
(:func:`require_dask` says so in one line).
"""

from __future__ import annotations

import contextlib
import importlib
import ipaddress
import socket
import struct
from dataclasses import dataclass

from mpipe.core.errors import UserError

#: Schemes a scheduler address may have (``tls`` is parsed and its port probed, but its
#: greeting is encrypted: not read).
SCHEMES = ("tcp", "tls")
#: Largest byte count of a scheduler's greeting frame believed, bytes (a handshake is a
#: few hundred bytes; ``HTTP/1.1`` read as a count is 3.5e18).
GREETING_LIMIT = 1 << 20
#: Port of the Dask dashboard (an HTTP server), named in the hint of a silent address.
DASHBOARD_PORT = 8787


@dataclass(frozen=True)
class SchedulerAddress:
    """A parsed scheduler address.

    Attributes
    ----------
    scheme : str
        ``tcp`` or ``tls``.
    host : str
        Host name or IP address (IPv6 without brackets).
    port : int
        TCP port, 1-65535.
    """

    scheme: str
    host: str
    port: int

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"


def parse_scheduler(address: str) -> SchedulerAddress:
    """Parse ``tcp://host:port`` (the scheme may be left out: ``host:port``).

    Raises
    ------
    ValueError
        Saying what is wrong with the address and what one looks like.
    """
    example = "expected tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786"
    text = str(address).strip()
    scheme, sep, rest = text.rpartition("://")
    scheme = scheme.lower() if sep else "tcp"
    if scheme not in SCHEMES:
        raise ValueError(f"{address!r}: scheme {scheme!r} not supported ({example})")
    if rest.startswith("["):  # IPv6: [addr]:port
        host, bracket, tail = rest[1:].partition("]")
        port_text = tail[1:] if bracket and tail.startswith(":") else ""
    else:
        host, colon, port_text = rest.rpartition(":")
        if not colon:
            host, port_text = rest, ""
    if not host or any(c.isspace() for c in host) or "/" in host or host.count(":") == 1:
        raise ValueError(f"{address!r}: no valid host ({example})")
    if not port_text:
        raise ValueError(f"{address!r}: no port ({example}; dask scheduler listens on 8786)")
    if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise ValueError(f"{address!r}: port {port_text!r} is not a number in 1-65535 ({example})")
    if ":" in host:
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise ValueError(f"{address!r}: {host!r} is not an IPv6 address ({example})") from None
    return SchedulerAddress(scheme, host, int(port_text))


def require_dask(option: str = "executor.kind") -> None:
    """Raise a one-line :class:`UserError` unless Dask's ``distributed`` can be imported."""
    try:
        importlib.import_module("distributed")
    except ImportError as exc:
        raise UserError(
            f"{option}: dask needs Dask's distributed package, which cannot be imported here "
            f"({exc}); install it (pip install 'mpipe[dask]') or use executor kind local"
        ) from None


def check_scheduler(address: str, timeout_s: float, option: str = "executor.scheduler") -> str:
    """Check that a Dask scheduler answers at ``address``; its address as Dask writes it.

    Parameters
    ----------
    address : str
        The address given (``tcp://host:port``).
    timeout_s : float
        Time allowed to connect and to hear the greeting, s (each).
    option : str
        The option or key that gave the address, named in the error.

    Returns
    -------
    str
        ``scheme://host:port``.

    Raises
    ------
    UserError
        One line naming ``option`` and the address: malformed, unknown host, nothing
        listening, no answer within ``timeout_s``, or something other than a scheduler.
    """
    try:
        parsed = parse_scheduler(address)
    except ValueError as exc:
        raise UserError(f"{option}: malformed scheduler address {exc}") from None
    where = f"{option}: {parsed}"
    try:
        sock = socket.create_connection((parsed.host, parsed.port), timeout=timeout_s)
    except socket.gaierror as exc:
        raise UserError(
            f"{where}: cannot reach it: unknown host {parsed.host!r} ({exc.strerror})"
        ) from None
    except ConnectionRefusedError:
        raise UserError(
            f"{where}: cannot reach it: connection refused (nothing listens on port "
            f"{parsed.port}); start the scheduler (dask scheduler) or fix the address"
        ) from None
    except TimeoutError:
        raise UserError(
            f"{where}: cannot reach it: no answer within {timeout_s:g} s (host down, "
            "unroutable address or a firewall); check the address and that the scheduler runs"
        ) from None
    except OSError as exc:
        raise UserError(f"{where}: cannot reach it ({exc.strerror or exc})") from None
    with contextlib.closing(sock):
        if parsed.scheme == "tcp":
            _check_greeting(sock, where, timeout_s)
    return str(parsed)


def _check_greeting(sock: socket.socket, where: str, timeout_s: float) -> None:
    """Read the first frame header; raise unless it is a Dask handshake's."""
    hint = (
        f"; port {DASHBOARD_PORT} is the dashboard's, the scheduler's is 8786 by default"
        if where.endswith(f":{DASHBOARD_PORT}")
        else ""
    )
    sock.settimeout(timeout_s)
    head = b""
    try:
        while len(head) < 8:
            part = sock.recv(8 - len(head))
            if not part:
                break
            head += part
    except TimeoutError:
        raise UserError(
            f"{where}: not a Dask scheduler: it sent nothing within {timeout_s:g} s (a "
            f"scheduler greets at once; an HTTP server waits for a request){hint}"
        ) from None
    except OSError as exc:
        raise UserError(f"{where}: the connection failed ({exc.strerror or exc})") from None
    if len(head) < 8:
        raise UserError(f"{where}: not a Dask scheduler: it closed the connection at once{hint}")
    (count,) = struct.unpack("<Q", head)
    if not 0 < count <= GREETING_LIMIT:
        shown = head.decode("ascii", "replace").strip()
        raise UserError(
            f"{where}: not a Dask scheduler: it answered {shown!r}, not a Dask greeting{hint}"
        )


__all__ = [
    "DASHBOARD_PORT",
    "GREETING_LIMIT",
    "SCHEMES",
    "SchedulerAddress",
    "check_scheduler",
    "parse_scheduler",
    "require_dask",
]
