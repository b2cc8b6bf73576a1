"""Prometheus metrics: requests, latency, store sizes. One registry per app, so test apps do not clash.
`Observe` counts and times every request."""

from __future__ import annotations

import time

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from index.store import Snapshot

METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter(
            "posedesc_requests", "HTTP requests", ["method", "route", "status"], registry=r
        )
        self.latency = Histogram(
            "posedesc_request_seconds",
            "HTTP request latency",
            ["route"],
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30),
            registry=r,
        )
        self.registration = Histogram(
            "posedesc_registration_seconds",
            "time to register an object, by stage",
            ["stage"],
            buckets=(0.1, 0.25, 0.5, 1, 2, 4, 8, 16, 32),
            registry=r,
        )
        self.failures = Counter(
            "posedesc_pipeline_failures",
            "failures inside the recognition pipeline, by stage: each rejects the answer it concerns",
            ["stage"],
            registry=r,
        )
        self.objects = Gauge("posedesc_objects", "registered objects", registry=r)
        self.templates = Gauge("posedesc_templates", "templates in a model's store", ["model"], registry=r)

    def failed(self, stage: str) -> None:
        self.failures.labels(stage).inc()

    def observe_registration(self, timings: dict[str, float]) -> None:
        for stage, seconds in timings.items():
            self.registration.labels(stage).observe(seconds)

    def render(self, snap: Snapshot) -> bytes:
        self.objects.set(len(snap.objects))
        for m, mi in snap.models.items():
            self.templates.labels(m).set(mi.size)
        return generate_latest(self.registry)


class Observe:
    """Pure ASGI middleware: each answered request counted (method, route template, status) and timed into
    the app's `Metrics`, once the app has sent it. A request that raises is left to the server's error
    handler, uncounted. Not Starlette's `BaseHTTPMiddleware`, which runs the app as a second task and
    passes the answer through a stream: 1.0 ms a `POST /recognize` more (medians of 400 requests to the app
    in-process, the pipeline's answer canned, interleaved with this; the shared 2-core machine)."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        status = 500

        async def seen_send(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        await self.app(scope, receive, seen_send)
        state = getattr(scope["app"].state, "posedesc", None)
        if state is not None:
            path = getattr(scope.get("route"), "path", "unmatched")  # the template: ids would blow up labels
            # any token is a method to HTTP: unknown ones share a label, or each would add a series
            method = scope["method"] if scope["method"] in METHODS else "other"
            state.metrics.requests.labels(method, path, str(status)).inc()
            state.metrics.latency.labels(path).observe(time.perf_counter() - t0)
