"""Prometheus metrics of one app instance (its own registry, created in the lifespan: no globals, so
several apps in one process, as in tests, do not collide)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from .worker import RenderWorker

# Stage latencies span 0.1 ms (decode) to tens of seconds (a PEM build at high quality on a CPU).
_BUCKETS = (0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)


class _WorkerCollector:
    """Queue depth, worker counters and PEM cache statistics, read at scrape time."""

    def __init__(self, worker: RenderWorker, counts):
        self.worker, self.counts = worker, counts

    def collect(self):
        w = self.worker
        g = GaugeMetricFamily("garment_render_queue_depth", "Jobs waiting for the GL thread")
        g.add_metric([], w.queue_depth)
        yield g
        g = GaugeMetricFamily("garment_render_queue_capacity", "Bound of the job queue")
        g.add_metric([], w.settings.queue_size)
        yield g
        g = GaugeMetricFamily("garment_render_gl_ready", "1 when the GL context is up and the worker runs")
        g.add_metric([], 1.0 if w.ready else 0.0)
        yield g
        c = CounterMetricFamily("garment_render_jobs", "Jobs run on the GL thread", labels=["outcome"])
        c.add_metric(["done"], w.stats.jobs_done)
        c.add_metric(["failed"], w.stats.jobs_failed)
        c.add_metric(["rejected"], w.stats.jobs_rejected)
        c.add_metric(["stopped"], w.stats.jobs_stopped)
        yield c
        c = CounterMetricFamily("garment_render_gl_busy_seconds", "Time the GL thread spent running jobs")
        c.add_metric([], w.stats.busy_ms_total / 1e3)
        yield c
        s = w.cache_stats()
        for name, value, doc in (("hits", s.hits, "PEM-set lookups served from GPU memory"),
                                 ("misses", s.misses, "PEM-set lookups not in GPU memory"),
                                 ("disk_hits", s.disk_hits, "PEM sets loaded from the disk cache"),
                                 ("disk_errors", s.disk_errors, "unreadable/unwritable disk cache entries"),
                                 ("builds", s.builds, "PEM sets built"),
                                 ("evictions", s.evictions, "PEM sets evicted from GPU memory")):
            c = CounterMetricFamily(f"garment_render_pem_cache_{name}", doc)
            c.add_metric([], value)
            yield c
        c = CounterMetricFamily("garment_render_pem_cache_build_seconds", "Time spent building PEM sets")
        c.add_metric([], s.build_ms_total / 1e3)
        yield c
        g = GaugeMetricFamily("garment_render_pem_cache_bytes", "GPU bytes of resident PEM sets")
        g.add_metric([], s.bytes)
        yield g
        g = GaugeMetricFamily("garment_render_pem_cache_entries", "Resident PEM sets")
        g.add_metric([], s.entries)
        yield g
        for name, n in self.counts().items():
            g = GaugeMetricFamily(f"garment_render_{name}", f"Registered {name}")
            g.add_metric([], n)
            yield g


class ServiceMetrics:
    def __init__(self, worker: RenderWorker, counts):
        """counts: a callable returning {"scenes": n, "environments": n, ...} at scrape time."""
        self.registry = CollectorRegistry()
        self.frames = Counter("garment_render_frames", "Frames rendered and answered", ["endpoint", "format"],
                              registry=self.registry)
        self.stage = Histogram("garment_render_stage_seconds", "Latency of each stage of a frame", ["stage"],
                               buckets=_BUCKETS, registry=self.registry)
        self.errors = Counter("garment_render_http_errors", "Error answers", ["status", "code"],
                              registry=self.registry)
        self.registry.register(_WorkerCollector(worker, counts))

    def observe_frame(self, endpoint: str, fmt: str, timings_ms: dict[str, float]) -> None:
        self.frames.labels(endpoint, fmt).inc()
        for stage, ms in timings_ms.items():
            self.stage.labels(stage).observe(ms / 1e3)

    def render(self) -> bytes:
        return generate_latest(self.registry)
