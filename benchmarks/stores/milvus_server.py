"""A real standalone Milvus server on loopback, from the PyPI package `milvus` (2.3.5, the `dev` extra),
for the tests (one per session) and `posedesc bench` (one per run): a temporary directory, free ports
chosen once, so a restart (`stop` then `start`) comes back on the same address with the same data.

Production uses the official images (deploy/docker-compose.milvus.yml); this is the same server binary."""

from __future__ import annotations

import contextlib
import os
import random
import socket
import time
from pathlib import Path
from typing import Any

#: the server's own threads on the 2 shared cores: Go's scheduler and knowhere's OpenMP
SERVER_ENV = {"GOMAXPROCS": "2", "OMP_NUM_THREADS": "1"}


def _ephemeral_low() -> int:
    """The lowest port the kernel hands out for outgoing connections and `bind(0)`."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_port(rng: random.Random | None = None, taken: frozenset[int] = frozenset()) -> int:
    """A free loopback port below the ephemeral range: a port from `bind(0)` can be taken, before the server
    listens on it, as the local end of any connection the machine opens meanwhile (CI lost a run to that)."""
    rng = rng or random.Random()
    low = _ephemeral_low()
    lo, hi = (20000, low - 1) if low > 21000 else (low, 65535)
    for _ in range(1000):
        port = rng.randint(lo, hi)
        if port in taken:
            continue
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free loopback port in {lo}-{hi}")


class LocalMilvus:
    """`start()` ~10 s; `uri` is what `POSEDESC_STORE` takes."""

    def __init__(self, base_dir: str | Path):
        from milvus import MilvusServer, MilvusServerConfig  # the dev extra; never in the serving image

        class Config(MilvusServerConfig):
            def try_bind_port(self, port: int) -> socket.socket | None:
                # the package's check binds without SO_REUSEADDR, so a restart fails for a minute on the
                # old connections' TIME_WAIT; the server itself (Go) reuses the address
                sock = socket.socket()
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    sock.bind(("127.0.0.1", port))
                    sock.listen()
                except OSError:
                    sock.close()
                    return None
                return sock

        self.base_dir = Path(base_dir)
        self._make = lambda: MilvusServer(Config(data_dir=str(self.base_dir)))
        self._choose_ports()
        self.started = False

    def _choose_ports(self) -> None:
        """Every listening port fixed once: the ports survive a restart, so clients reconnect to the same URI."""
        self.server: Any = self._make()
        keys = [k for k in self.server.config.configurable_items if k.endswith("_port")] + ["webservice_port"]
        ports: dict[str, int] = {}
        for k in keys:
            ports[k] = free_port(taken=frozenset(ports.values()))
        self.server.webservice_port = ports.pop("webservice_port")
        self.server.config.update(**ports)
        self.port = ports["proxy_port"]

    @property
    def uri(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, timeout: float = 120.0) -> None:
        saved = {k: os.environ.get(k) for k in SERVER_ENV}
        os.environ.update(SERVER_ENV)
        try:
            for attempt in range(5):
                try:
                    self.server.start()  # waits for its /healthz
                    break
                except RuntimeError as e:  # "set X_port=N, but bind failed": taken since it was chosen
                    if "bind failed" not in str(e) or attempt == 4:
                        raise
                    if self.started:  # a restart keeps its address: wait for the port to come free
                        time.sleep(2.0)
                    else:
                        self._choose_ports()
            self.started = True
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        self._wait_serving(timeout)

    def _wait_serving(self, timeout: float) -> None:
        """Its health check answers before the proxy takes requests: wait until a client call works."""
        from pymilvus import MilvusClient

        t0, last = time.monotonic(), None
        while time.monotonic() - t0 < timeout:
            try:
                client = MilvusClient(self.uri, timeout=5)
                client.list_collections(timeout=5)
                client.close()
                return
            except Exception as e:  # not up yet
                last = e
                time.sleep(0.3)
        raise TimeoutError(f"Milvus at {self.uri} did not serve within {timeout} s: {last}")

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after a second (the package's own stop); the data stay in `base_dir`."""
        with contextlib.suppress(Exception):
            self.server.stop()

    def __enter__(self) -> LocalMilvus:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
