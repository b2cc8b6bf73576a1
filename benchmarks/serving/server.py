"""The real service for the HTTP benchmarks: `posedesc serve` (uvicorn) in a child process on a free
loopback port, on a data dir of the benchmark's own, stopped with SIGTERM as a deployment would."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import httpx

from benchmarks.timing import ROOT


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """`with Server(data_dir, models, env) as url:` serves until the block ends. `env`: POSEDESC_* settings
    over this process's environment; None removes a variable (the setting's default)."""

    def __init__(self, data_dir: Path, models: Path, env: Mapping[str, str | None], timeout_s: float = 300.0):
        self.data_dir, self.models, self.env, self.timeout_s = data_dir, models, env, timeout_s
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = data_dir.parent / f"server-{self.port}.log"
        self.proc: subprocess.Popen | None = None

    def __enter__(self) -> str:
        cmd = [sys.executable, "-m", "posedesc.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port)]
        cmd += ["--data-dir", str(self.data_dir), "--models", str(self.models), "--log-level", "warning"]
        with open(self.log, "wb") as out:  # the child keeps its own descriptor
            self.proc = subprocess.Popen(
                cmd, cwd=ROOT, env=self._environment(), stdout=out, stderr=subprocess.STDOUT
            )
        self._wait_ready()
        return self.url

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def _environment(self) -> dict[str, str]:
        merged: dict[str, str | None] = {**os.environ, **self.env}
        return {k: v for k, v in merged.items() if v is not None}

    def _wait_ready(self) -> None:
        end = time.monotonic() + self.timeout_s
        while time.monotonic() < end:
            if self.proc is None or self.proc.poll() is not None:
                raise RuntimeError(f"the service exited during start-up:\n{self._tail()}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"the service was not ready after {self.timeout_s:.0f} s:\n{self._tail()}")

    def _tail(self) -> str:
        return self.log.read_text(errors="replace")[-3000:] if self.log.is_file() else ""

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
