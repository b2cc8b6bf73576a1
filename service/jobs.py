"""Registrations that outlive their request: `POST /objects` answers 202 with a job id when it takes
longer than `sync_seconds`; `GET /jobs/{id}` tells how it went.

With a shared store (Milvus) replicas sit behind a load balancer, so a client polls whichever replica it
reaches: each job's state is then also a file in the shared data directory (`jobs/<id>.json`, written
whole at each change), which any replica reads. A replica that dies leaves its running jobs running in
their files: a job whose replica has not touched its heartbeat file (`replicas/<id>`) for `STALE`
seconds is reported failed (nothing of it is live: registrations are all-or-nothing). The queue limit
stays per replica: it protects that replica's render thread."""

from __future__ import annotations

import contextlib
import json
import os
import threading
import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

from index.store.shared_files import SharedFiles

FIELDS = ("job_id", "name", "status", "created", "result", "error", "code", "progress")  # shared files
STALE = 5.0  # seconds without a heartbeat: the replica running a job is gone
HEARTBEAT = 1.0


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
    replica: str = ""
    #: how far a registration is: {"stage": render | embed | store, "done": n, "total": N}
    #: (`index.templates.register.Progress`); replaced whole, so a reader never sees half an update
    progress: dict[str, Any] | None = None

    def fail(self, code: int, error: str) -> None:
        self.code, self.error, self.status = code, error, "failed"

    def advance(self, stage: str, done: int, total: int) -> None:
        """An `index.templates.register.Progress`: what `GET /jobs/{id}` shows while the job runs."""
        self.progress = {"stage": stage, "done": done, "total": total}


class Busy(Exception):
    """As many jobs are running as the limit allows."""


class Jobs:
    """The last `keep` jobs, thread-safe."""

    def __init__(self, keep: int = 1000, files: SharedFiles | None = None):
        self._jobs: OrderedDict[str, Job] = OrderedDict()
        self._lock = threading.Lock()
        self.keep = keep
        self.files = files
        self.replica = f"{os.uname().nodename}-{os.getpid()}-{uuid.uuid4().hex[:6]}"
        self._stop = threading.Event()
        if files is not None:
            self._beat()
            threading.Thread(target=self._heart, name="jobs-heartbeat", daemon=True).start()

    def _beat(self) -> None:
        assert self.files is not None
        with contextlib.suppress(OSError):  # a full shared disk: jobs elsewhere look stale, nothing worse
            self.files.write(f"replicas/{self.replica}", str(time.time()).encode())

    def _heart(self) -> None:
        while not self._stop.wait(HEARTBEAT):
            self._beat()

    def close(self) -> None:
        self._stop.set()

    def save(self, job: Job) -> None:
        """Writes the job's state where every replica reads it (no-op without a shared directory)."""
        if self.files is None:
            return
        body = {k: getattr(job, k) for k in FIELDS}
        self.files.write(f"jobs/{job.job_id}.json", json.dumps({**body, "replica": self.replica}).encode())

    def new(self, name: str, limit: int | None = None) -> Job:
        """A running job; raises Busy when `limit` jobs are running already. Counting and adding are one
        step under the lock: checked apart, concurrent uploads would all see room and all be queued."""
        job = Job(uuid.uuid4().hex, name, replica=self.replica)
        with self._lock:
            if limit is not None and self._running() >= limit:
                raise Busy(f"{limit} registrations are queued already")
            self._jobs[job.job_id] = job
            while len(self._jobs) > self.keep:
                old, _ = self._jobs.popitem(last=False)
                if self.files is not None:
                    self.files.remove(f"jobs/{old}.json")
        self.save(job)
        return job

    def discard(self, job: Job) -> None:
        """Forgets a job that never started (its upload was refused), so it frees its place at once."""
        with self._lock:
            self._jobs.pop(job.job_id, None)
        if self.files is not None:
            self.files.remove(f"jobs/{job.job_id}.json")

    def get(self, job_id: str) -> Job | None:
        with self._lock:
            job = self._jobs.get(job_id)
        if job is not None or self.files is None or not job_id.isalnum():
            return job
        data = self.files.read(f"jobs/{job_id}.json")  # another replica's
        if data is None:
            return None
        raw = json.loads(data)
        job = Job(**{k: raw.get(k) for k in FIELDS})
        beat = self.files.read(f"replicas/{raw.get('replica')}")
        if job.status == "running" and (beat is None or time.time() - float(beat) > STALE):
            job.fail(
                503, "the replica running this registration stopped; nothing was registered: send it again"
            )
        return job

    def running(self) -> int:
        with self._lock:
            return self._running()

    def _running(self) -> int:
        return sum(j.status == "running" for j in self._jobs.values())
