"""Loopback TCP servers for the UR connection checks: one that never speaks, one that does.

``SilentListener`` is the mistyped-address case: a device whose port 30004 accepts TCP and
then says nothing (ur_rtde's constructors block for minutes on it). ``RTDEVersionServer``
answers RTDE's first handshake package the way a UR controller does (UR's RTDE guide:
big-endian uint16 size, uint8 type; RTDE_REQUEST_PROTOCOL_VERSION = 86 with a uint16
version, answered by type 86 with a uint8 "accepted"). Its codec is written here with plain
``struct`` calls, independently of robots/drivers/ur.py.
"""

from __future__ import annotations

import socket
import struct
import threading


class _Server:
    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind((host, port))
        self._sock.listen(8)
        self.host, self.port = self._sock.getsockname()
        self.received: list[bytes] = []
        self._clients: list[socket.socket] = []
        self._running = True
        threading.Thread(target=self._accept_loop, daemon=True).start()

    def _accept_loop(self):
        while self._running:
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            self._clients.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn):
        raise NotImplementedError

    def close(self):
        self._running = False
        try:  # wakes the thread blocked in accept(); close() alone would leave it listening
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()
        for c in self._clients:
            c.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class SilentListener(_Server):
    """Accepts every connection, reads whatever arrives, never answers."""

    def _serve(self, conn):
        try:
            while chunk := conn.recv(4096):
                self.received.append(chunk)
        except OSError:
            return


class RTDEVersionServer(_Server):
    """Answers RTDE_REQUEST_PROTOCOL_VERSION with accepted = 1 for version 2 (else 0)."""

    def _serve(self, conn):
        try:
            data = b""
            while len(data) < 5:
                chunk = conn.recv(5 - len(data))
                if not chunk:
                    return
                data += chunk
            self.received.append(data)
            size, kind, version = struct.unpack(">HBH", data)
            if size == 5 and kind == 86:
                conn.sendall(struct.pack(">HBB", 4, 86, 1 if version == 2 else 0))
        except OSError:
            return
