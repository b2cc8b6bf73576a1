"""Registrations that outlive their request: `POST /objects` answers 202 with a job id when it takes
longer than `sync_seconds`; `GET /jobs/{id}` tells how it went."""

from __future__ import annotations

import threading
import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any


@dataclass
class Job:
    job_id: str
    name: str
    status: str = "running"  # running | done | failed
    created: float = field(default_factory=time.time)
    result: dict[str, Any] | None = None
    error: str | None = None
    #: the HTTP status a failure answers with: 422 bad mesh, 409 name taken, 507 disk full, 500 a bug
    code: int | None = None

    def fail(self, code: int, error: str) -> None:
        self.code, self.error, self.status = code, error, "failed"


class Busy(Exception):
    """As many jobs are running as the limit allows."""


class Jobs:
    """The last `keep` jobs, thread-safe."""

    def __init__(self, keep: int = 1000):
        self._jobs: OrderedDict[str, Job] = OrderedDict()
        self._lock = threading.Lock()
        self.keep = keep

    def new(self, name: str, limit: int | None = None) -> Job:
        """A running job; raises Busy when `limit` jobs are running already. Counting and adding are one
        step under the lock: checked apart, concurrent uploads would all see room and all be queued."""
        job = Job(uuid.uuid4().hex, name)
        with self._lock:
            if limit is not None and self._running() >= limit:
                raise Busy(f"{limit} registrations are queued already")
            self._jobs[job.job_id] = job
            while len(self._jobs) > self.keep:
                self._jobs.popitem(last=False)
        return job

    def discard(self, job: Job) -> None:
        """Forgets a job that never started (its upload was refused), so it frees its place at once."""
        with self._lock:
            self._jobs.pop(job.job_id, None)

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def running(self) -> int:
        with self._lock:
            return self._running()

    def _running(self) -> int:
        return sum(j.status == "running" for j in self._jobs.values())
