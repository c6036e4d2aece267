"""serve's TCP endpoint, in process: the socket options issue #10 §4 asks for."""

from __future__ import annotations

import socket
import time

from serial_protocol.pacing import LinePacer
from sim.endpoints import TcpEndpoint


def test_the_client_socket_has_tcp_nodelay():
    """An answer leaves the server when it is written, not after the client's delayed ACK
    (~40 ms on Linux; benchmarks/bench_link.py measures 4 ms against 44 ms)."""
    endpoint = TcpEndpoint(LinePacer(46080.0, 2304), "127.0.0.1", 0)
    try:
        host, port = endpoint.address.removeprefix("socket://").rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=30):
            deadline_s = time.monotonic() + 60.0
            while endpoint.counters["clients"] == 0 and time.monotonic() < deadline_s:
                endpoint.receive(256)  # accepts the connection
                time.sleep(0.01)
            assert endpoint.counters["clients"] == 1
            client = endpoint._client
            assert client is not None
            assert client.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY)
    finally:
        endpoint.close()
