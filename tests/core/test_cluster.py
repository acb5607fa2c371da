"""A scheduler address that cannot serve: one line naming it, within the time allowed.

Each far end is a socket of this process bound before the check starts (listening is
synchronous: nothing to wait for): an HTTP server, a service that answers at once with
non-Dask bytes, one that hangs up, a port where nothing listens, and a reserved TEST-NET
address (RFC 5737) that no host answers. A real scheduler is checked in
tests/inversion/fit/test_execution.py.
"""

import contextlib
import http.server
import socket
import struct
import sys
import threading
import time

import pytest

from mpipe.core.cluster import check_scheduler, parse_scheduler, require_dask
from mpipe.core.errors import UserError


@pytest.mark.parametrize(
    ("text", "scheme", "host", "port"),
    [
        ("tcp://10.0.0.5:8786", "tcp", "10.0.0.5", 8786),
        ("10.0.0.5:8786", "tcp", "10.0.0.5", 8786),
        ("TLS://sched.lab:9000", "tls", "sched.lab", 9000),
        ("tcp://[::1]:8786", "tcp", "::1", 8786),
    ],
)
def test_an_address_is_parsed(text, scheme, host, port):
    parsed = parse_scheduler(text)
    assert (parsed.scheme, parsed.host, parsed.port) == (scheme, host, port)
    assert parse_scheduler(str(parsed)) == parsed  # written back as it parses


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("tcp://10.0.0.5", "no port"),
        ("tcp://10.0.0.5:87x6", "not a number"),
        ("tcp://10.0.0.5:70000", "not a number in 1-65535"),
        ("udp://10.0.0.5:8786", "scheme 'udp'"),
        ("tcp://:8786", "no valid host"),
        ("my scheduler:8786", "no valid host"),
        ("http://10.0.0.5:8787/status", "scheme 'http'"),
        ("tcp://[::1:8786", "no port"),
    ],
)
def test_a_malformed_address_says_what_is_wrong(text, why):
    with pytest.raises(ValueError, match=why):
        parse_scheduler(text)
    with pytest.raises(UserError, match=rf"^--scheduler: malformed scheduler address .*{why}"):
        check_scheduler(text, 1.0, "--scheduler")


@contextlib.contextmanager
def serving(handle):
    """A TCP server on 127.0.0.1 whose every connection goes to ``handle(conn)``."""
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def loop():
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                handle(conn)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        stop.set()
        server.close()


@contextlib.contextmanager
def http_server():
    """Python's own HTTP server (it waits for a request before it says anything)."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def _timed(address, timeout_s=0.5):
    t0 = time.perf_counter()
    with pytest.raises(UserError) as err:
        check_scheduler(address, timeout_s)
    return str(err.value), time.perf_counter() - t0


def test_an_http_server_is_not_a_scheduler_within_the_timeout():
    with http_server() as address:
        message, wall = _timed(address)
    assert message.startswith(f"executor.scheduler: {address}: not a Dask scheduler: it sent ")
    assert "\n" not in message
    assert wall < 0.5 + 2.0  # the greeting's timeout, not Dask's minutes


def test_a_service_answering_other_bytes_is_not_a_scheduler():
    # the bytes that Dask's client read as a frame of 3.07 EiB
    def reply(conn):
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")

    with serving(reply) as address:
        message, _ = _timed(address)
    assert "not a Dask scheduler: it answered 'HTTP/1.1'" in message


def test_a_service_that_hangs_up_is_not_a_scheduler():
    with serving(lambda conn: None) as address:
        message, _ = _timed(address)
    assert "not a Dask scheduler: it closed the connection at once" in message


def test_a_dask_like_greeting_passes():
    # the frame header a scheduler sends first: its byte count, small
    def greet(conn):
        conn.sendall(struct.pack("<Q", 120) + b"\0" * 120)

    with serving(greet) as address:
        assert check_scheduler(address, 1.0) == address


def test_a_refused_port_is_one_line_at_once():
    with socket.socket() as s:  # bound, not listening: the port refuses
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
        message, wall = _timed(address)
    assert "cannot reach it: connection refused" in message and address in message
    assert wall < 2.0


def test_an_unroutable_address_is_one_line_within_the_timeout():
    # TEST-NET-1: no host answers (refused at once, or silent until the timeout, by network)
    message, wall = _timed("tcp://192.0.2.1:8786", 0.3)
    assert message.startswith("executor.scheduler: tcp://192.0.2.1:8786: cannot reach it")
    assert wall < 0.3 + 2.0


def test_dask_missing_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # blocks the import
    with pytest.raises(UserError, match=r"^executor\.kind: dask needs Dask's distributed"):
        require_dask()
