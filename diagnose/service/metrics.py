"""Optional Prometheus metrics for `stiction monitor` (needs ``prometheus-client``).

Per loop: ``stiction_s_pct``, ``stiction_j_pct``, ``stiction_severity``, ``stiction_confidence``,
``stiction_detected`` (1/0), ``stiction_probability`` from the latest window,
``stiction_sticky_share`` (the share of the loop's last windows, at most 7, that showed stiction),
``stiction_windows_total{status}``; from the
poller (read when Prometheus scrapes, nothing per poll): ``stiction_polls_total``,
``stiction_polls_failed_total``, ``stiction_polls_missed_total``. Served on 127.0.0.1 unless
another address is given.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, Mapping

from ..errors import StictionError

if TYPE_CHECKING:
    from .pipeline import Diagnosis


class Metrics:
    """Prometheus gauges/counters in their own registry, served over HTTP.

    Parameters
    ----------
    port : int
        TCP port (0 picks a free one; see ``.port``).
    addr : str
        Listen address (default loopback).
    poll_stats : callable returning {loop: stats}, optional
        Poller statistics (objects with ``polls``, ``failed``, ``missed``), read at scrape time.
    """

    def __init__(self, port: int, *, addr: str = "127.0.0.1",
                 poll_stats: Callable[[], Mapping[str, Any]] | None = None) -> None:
        try:
            from prometheus_client import CollectorRegistry, Counter, Gauge, start_http_server
            from prometheus_client.core import CounterMetricFamily
        except ImportError:
            raise StictionError("--metrics-port needs prometheus-client: pip install 'stiction[prometheus]'") from None
        self.registry = CollectorRegistry()
        g = lambda name, doc: Gauge(name, doc, ["loop"], registry=self.registry)  # noqa: E731
        self.S = g("stiction_s_pct", "Identified S (deadband + stickband), % of valve span")
        self.J = g("stiction_j_pct", "Identified J (slip jump), % of valve span")
        self.severity = g("stiction_severity", "Severity score 0-100 of the latest window")
        self.confidence = g("stiction_confidence", "Confidence in the latest verdict, 0-1")
        self.detected = g("stiction_detected", "1 when the latest window shows stiction")
        self.probability = g("stiction_probability", "Probability of stiction of the latest window, 0-1")
        self.sticky_share = g("stiction_sticky_share",
                              "Share of the loop's last windows (at most 7) that showed stiction, 0-1")
        self.windows = Counter("stiction_windows", "Windows diagnosed", ["loop", "status"], registry=self.registry)

        class _PollCollector:
            def collect(self_inner):  # noqa: N805
                stats = poll_stats() if poll_stats is not None else {}
                fams = [CounterMetricFamily("stiction_polls", "Modbus polls", labels=["loop"]),
                        CounterMetricFamily("stiction_polls_failed", "Failed Modbus polls", labels=["loop"]),
                        CounterMetricFamily("stiction_polls_missed", "Missed Modbus poll ticks", labels=["loop"])]
                for loop, st in stats.items():
                    fams[0].add_metric([loop], float(st.polls))
                    fams[1].add_metric([loop], float(st.failed))
                    fams[2].add_metric([loop], float(st.missed))
                return fams

        self.registry.register(_PollCollector())
        try:
            server = start_http_server(port, addr=addr, registry=self.registry)
        except OSError as exc:
            raise StictionError(f"cannot serve metrics on {addr}:{port}: {exc}; pick another --metrics-port") from None
        self._server = server[0] if isinstance(server, tuple) else server
        self.port = self._server.server_port if self._server is not None else port

    def observe(self, loop: str, diag: Diagnosis, sticky_runs: tuple[int, int, Any] | None = None) -> None:
        """Update the gauges from one window's diagnosis (``sticky_runs``: the loop's last windows
        that showed stiction and how many were counted, `diagnose.service.history.sticky_runs`)."""
        ident = diag.identification
        share = None if not sticky_runs else sticky_runs[0] / sticky_runs[1]
        # the gauges are in % of span; S and J are in OP's units (a fraction of span, say)
        k = ident.pct_per_op_unit
        S = None if ident.S_pct is None else ident.S_pct * k
        J = None if ident.J_pct is None else ident.J_pct * k
        for gauge, value in ((self.S, S), (self.J, J), (self.confidence, ident.confidence),
                             (self.severity, diag.severity.score), (self.probability, ident.stiction_probability),
                             (self.sticky_share, share)):
            if value is not None:
                gauge.labels(loop).set(float(value))
        self.detected.labels(loop).set(1.0 if ident.stiction else 0.0)
        self.windows.labels(loop, "ok").inc()

    def failed(self, loop: str) -> None:
        self.windows.labels(loop, "failed").inc()

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
