"""Prometheus metrics: requests, latency, store sizes. One registry per app, so test apps do not clash."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

from index.store import Snapshot


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
        self.objects = Gauge("posedesc_objects", "registered objects", registry=r)
        self.templates = Gauge("posedesc_templates", "templates in a model's store", ["model"], registry=r)

    def observe_registration(self, timings: dict[str, float]) -> None:
        for stage, seconds in timings.items():
            self.registration.labels(stage).observe(seconds)

    def render(self, snap: Snapshot) -> bytes:
        self.objects.set(len(snap.objects))
        for m, mi in snap.models.items():
            self.templates.labels(m).set(mi.size)
        return generate_latest(self.registry)
