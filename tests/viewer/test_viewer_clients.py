"""Many viewers: a client that stops reading holds a bounded amount of the server's memory, whatever
the map sends meanwhile (newer updates of a node replace older ones not yet sent)."""

from __future__ import annotations

import base64
import os
import socket

import numpy as np

from helpers.viewer import blob_map, wait_until


def stalled_client(port: int) -> socket.socket:
    """A websocket handshake on a raw socket that then never reads."""
    import viser

    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                  f"Sec-WebSocket-Protocol: viser-v{viser.__version__}\r\n\r\n").encode())
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert b" 101 " in head.split(b"\r\n")[0], head
    return sock


def test_a_stalled_client_holds_a_bounded_buffer(server):
    from app.snapshot import KeyframeView, MapSnapshot
    from app.viewer.scene import MapLayer

    sock = stalled_client(server.get_port())
    ws = server._websock_server
    try:
        wait_until(lambda: len(ws._live_connections) == 1, 60, what="the stalled connection")
        cid = next(iter(ws._live_connections))
        layer = MapLayer(server, consolidate_every=1)
        kfs = (KeyframeView(0, np.eye(4), np.zeros((4, 4, 3), np.uint8)),)
        m = blob_map(20_000, 0).to_numpy()                  # ~0.7 MB per chunk message
        held = []
        for version in range(1, 41):                        # 40 map updates, ~28 MB sent in all
            g = {k: np.array(v) for k, v in m.items()}
            g["means"] += 0.001 * version
            assert layer.update(MapSnapshot(version, "running", version, 100, version, g, kfs),
                                force_consolidate=True)
            if version % 10 == 0:
                connection = ws._live_connections.get(cid)
                pending = connection.transport.get_write_buffer_size() if connection else 0
                held.append((pending, len(ws._broadcast_buffer.message_from_id)))
        assert cid in ws._live_connections                  # still connected, still served
        # what waits for it stays at about one window of messages, not 40 updates' worth
        assert max(p for p, _ in held) < 8 * 2**20, held
        assert held[-1][1] <= held[0][1] + 2, held           # the shared buffer keeps the newest update only
    finally:
        sock.close()
