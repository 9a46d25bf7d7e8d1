"""A network source as a fusion plugin: lines of the log format received as UDP datagrams.

``fusion run CONFIG --input udp://HOST:PORT`` (and ``fusion tui --input ...``) binds HOST:PORT and reads
datagrams, each holding one or more complete lines. ``?idle=S`` ends the stream after S seconds without a
datagram (default: never; Ctrl-C or ``close()`` ends it).
"""
from __future__ import annotations

import socket
import threading
from typing import Iterator
from urllib.parse import parse_qs, urlsplit

from pydantic import Field

from fusion.api import ConfigError, InputError, Params, Source


class UdpSource(Source):
    """Receives log lines as UDP datagrams on ``host:port`` (``udp://HOST:PORT[?idle=S]``)."""

    name = "udp"
    schemes = ("udp",)
    live = True
    bound = threading.Event()  # set once a socket is bound (lets a test start sending)

    class Params(Params):
        host: str = "127.0.0.1"
        port: int = Field(ge=0, le=65535)
        idle: float | None = Field(None, gt=0, description="s without a datagram that end the stream")

    @classmethod
    def from_url(cls, url: str, **options) -> "UdpSource":
        parts = urlsplit(url)
        if parts.port is None:
            raise ConfigError(f"{url}: expected udp://HOST:PORT")
        query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
        return cls(cls.Params(host=parts.hostname or "127.0.0.1", port=parts.port, **query, **options))

    def __init__(self, params=None, context=None):
        super().__init__(params, context)
        self._sock: socket.socket | None = None
        self._closed = threading.Event()

    @property
    def label(self) -> str:
        return f"udp://{self.params.host}:{self.params.port}"

    def open(self) -> "UdpSource":
        if self._sock is None:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                sock.bind((self.params.host, self.params.port))
            except OSError as exc:
                sock.close()
                raise InputError(f"cannot listen on {self.label}: {exc.strerror or exc}") from None
            sock.settimeout(0.1)
            self._sock = sock
            UdpSource.bound.set()
        return self

    def close(self) -> None:
        self._closed.set()

    def lines(self) -> Iterator[str]:
        sock = self.open()._sock
        waited = 0.0
        try:
            while not self._closed.is_set():
                try:
                    data = sock.recv(65536)
                except socket.timeout:
                    waited += 0.1
                    if self.params.idle is not None and waited >= self.params.idle:
                        return
                    continue
                waited = 0.0
                for line in data.decode("utf-8", "replace").splitlines():
                    yield line + "\n"
        finally:
            sock.close()
            self._sock = None
