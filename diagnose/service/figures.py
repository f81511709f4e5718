"""Report figures as PNG bytes: trends, phase plots, error surface, NARX-SP free run, spectrum.

Lean on purpose (a nightly batch draws thousands): matplotlib's object API on the Agg canvas (no
pyplot, no global state), one reusable `Figure` per layout per process (cleared, not rebuilt), low
dpi, long series reduced to a min/max envelope before drawing. matplotlib is imported only when a
figure is drawn. Functions return ``{name: png_bytes}``; the caller decides where files go.
"""

from __future__ import annotations

import io
from typing import Any, Mapping

import numpy as np

DPI = 72
#: Longest series drawn as is; longer ones become a min/max envelope of this many buckets.
MAX_POINTS = 1200
#: The phase plots show the last this many samples (a whole long record is an unreadable tangle).
PHASE_SAMPLES = 1000
_FIGS: dict[tuple[float, float], Any] = {}

COLORS = {"pv": "#1f77b4", "sp": "#555555", "op": "#d62728", "mv": "#2ca02c", "model": "#ff7f0e",
          "narx": "#9467bd"}


def _figure(w_in: float, h_in: float) -> Any:
    """A cleared, reusable Agg figure of this size."""
    key = (w_in, h_in)
    fig = _FIGS.get(key)
    if fig is None:
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(w_in, h_in), dpi=DPI)
        FigureCanvasAgg(fig)
        _FIGS[key] = fig
    fig.clf()
    return fig


def _png(fig: Any) -> bytes:
    buf = io.BytesIO()
    # fast zlib level: files ~1.5x larger, encoding several times faster
    fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": 1})
    return buf.getvalue()


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """Reduce a long series to at most ``2 * max_points + 2`` points keeping each bucket's min and max.

    The oscillation's amplitude and shape survive (a plain stride would alias it away). Buckets
    cover the whole record (the last one may be shorter) and the first and last samples are kept,
    so the drawn line spans exactly the record's time range.
    """
    t = np.asarray(t)
    y = np.asarray(y)
    n = y.shape[0]
    if n <= 2 * max_points:
        return t, y
    m = -(-n // max_points)  # samples per bucket, rounded up: at most max_points buckets
    nb = -(-n // m)
    pad = nb * m - n
    # the last bucket is padded with the last sample: it changes neither its min nor its max
    yb = np.concatenate([y, np.repeat(y[-1:], pad)]).reshape(nb, m)
    lo_i = np.argmin(yb, axis=1)
    hi_i = np.argmax(yb, axis=1)
    base = np.arange(nb) * m
    first = np.minimum(base + np.minimum(lo_i, hi_i), n - 1)
    second = np.minimum(base + np.maximum(lo_i, hi_i), n - 1)
    idx = np.empty(2 * nb + 2, dtype=np.intp)
    idx[0], idx[-1] = 0, n - 1
    idx[1:-1:2], idx[2:-1:2] = first, second
    return t[idx], y[idx]


def _time_axis(record: Any) -> tuple[np.ndarray, str]:
    t = record.t_s
    dur = record.duration_s
    if dur > 4 * 3600:
        return t / 3600.0, "time (h)"
    if dur > 600:
        return t / 60.0, "time (min)"
    return t, "time (s)"


def _plot(ax: Any, t: np.ndarray, y: np.ndarray, **kw: Any) -> None:
    tt, yy = envelope(t, y)
    ax.plot(tt, yy, lw=kw.pop("lw", 0.8), **kw)


def record_limits(*series: np.ndarray | None, margin: float = 0.08) -> tuple[float, float]:
    """Axis range of recorded series, padded by ``margin`` of their span.

    Model lines are drawn inside the record's range: a simulation started from the wrong state
    can swing far off in its first samples, and that start-up transient must not set the scale.
    """
    vals = [np.asarray(v, dtype=float) for v in series if v is not None]
    vals = [v[np.isfinite(v)] for v in vals]
    vals = [v for v in vals if v.size]
    if not vals:
        return 0.0, 1.0
    lo = min(float(v.min()) for v in vals)
    hi = max(float(v.max()) for v in vals)
    span = hi - lo
    if span <= 0:
        span = max(abs(hi), 1.0) * 0.1
    return lo - margin * span, hi + margin * span


def _sticky(diag: Any) -> bool:
    from .pipeline import stiction_present

    return bool(stiction_present(diag.result))


def _model_path(diag: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fitted model's (valve path, PV) over the whole record, as the report may draw them.

    The valve path is the sticky valve that S and J describe: from the valve fit on the recorded
    stem position when S and J came from it, else from the OP-PV Hammerstein fit. On a
    no-stiction verdict no sticky valve path is drawn, and PV comes from the linear (no-stiction)
    fit where identification made one.
    """
    ident = diag.identification
    sticky = _sticky(diag)
    fit = getattr(ident, "fit", None)
    if not sticky and getattr(ident, "linear_fit", None) is not None:
        fit = ident.linear_fit
    mv_hat = pv_hat = None
    if fit is not None:
        try:
            mv, pv = fit.simulate(diag.record.op)
            mv_hat, pv_hat = np.asarray(mv, dtype=float), np.asarray(pv, dtype=float)
        except Exception:
            mv_hat = pv_hat = None
    valve = getattr(ident, "valve_fit", None)
    if sticky and valve is not None and diag.result.get("method") == "op_mv":
        try:
            mv_hat = np.asarray(valve.simulate(diag.record.op), dtype=float)
        except Exception:
            mv_hat = None
    if not sticky:
        mv_hat = None
    return mv_hat, pv_hat


def trends(diag: Any, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    rec = diag.record
    t, tlabel = _time_axis(rec)
    fig = _figure(8.0, 4.6)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if pv_hat is not None:
        _plot(ax1, t, pv_hat, color=COLORS["model"], label="model PV", alpha=0.8, zorder=1)
    if rec.sp is not None:
        _plot(ax1, t, rec.sp, color=COLORS["sp"], label="SP", zorder=2)
    _plot(ax1, t, rec.pv, color=COLORS["pv"], label="PV", zorder=3)
    ax1.set_ylim(*record_limits(rec.pv, rec.sp))
    unit = rec.units.get("pv", "")
    ax1.set_ylabel(f"PV{' (' + unit + ')' if unit else ''}")
    ax1.legend(loc="upper right", fontsize=7, ncol=3)
    if mv_hat is not None:
        _plot(ax2, t, mv_hat, color=COLORS["model"], label="model valve", alpha=0.8, zorder=1)
    _plot(ax2, t, rec.op, color=COLORS["op"], label="OP", zorder=2)
    if rec.mv is not None:
        _plot(ax2, t, rec.mv, color=COLORS["mv"], label="MV", zorder=3)
    ax2.set_ylim(*record_limits(rec.op, rec.mv))
    ax2.set_ylabel("% of span")
    ax2.set_xlabel(tlabel)
    ax2.set_xlim(float(t[0]), float(t[-1]))
    ax2.legend(loc="upper right", fontsize=7, ncol=3)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.97, bottom=0.11, hspace=0.08)
    return _png(fig)


def phase(diag: Any, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    """OP-PV (and OP-MV where the record has MV) with the fitted model's path under it."""
    rec = diag.record
    two = rec.mv is not None
    fig = _figure(8.0 if two else 4.6, 3.8)
    axes = fig.subplots(1, 2 if two else 1, squeeze=False)[0]
    s = slice(max(rec.n - PHASE_SAMPLES, 0), None)  # the last part: whole cycles stay legible
    # the recording on top, the model dashed beneath it: where they agree the recording shows
    ax = axes[0]
    if pv_hat is not None:
        ax.plot(rec.op[s], pv_hat[s], lw=1.0, ls="--", color=COLORS["model"], label="fitted model", zorder=1)
    ax.plot(rec.op[s], rec.pv[s], lw=0.8, color=COLORS["pv"], label="record", zorder=2)
    ax.set_xlim(*record_limits(rec.op[s]))
    ax.set_ylim(*record_limits(rec.pv[s]))
    ax.set_xlabel("OP (%)")
    ax.set_ylabel("PV")
    ax.set_title(f"OP-PV, last {min(rec.n, PHASE_SAMPLES)} samples", fontsize=9)
    ax.legend(loc="best", fontsize=7)
    if two:
        ax = axes[1]
        if mv_hat is not None:
            ax.plot(rec.op[s], mv_hat[s], lw=1.0, ls="--", color=COLORS["model"], label="fitted valve", zorder=1)
        ax.plot(rec.op[s], rec.mv[s], lw=0.8, color=COLORS["mv"], label="record", zorder=2)
        ax.set_xlim(*record_limits(rec.op[s]))
        ax.set_ylim(*record_limits(rec.mv[s]))
        ax.set_xlabel("OP (%)")
        ax.set_ylabel("MV (%)")
        ax.set_title(f"OP-MV, last {min(rec.n, PHASE_SAMPLES)} samples", fontsize=9)
        ax.legend(loc="best", fontsize=7)
    fig.subplots_adjust(left=0.15 if not two else 0.09, right=0.98, top=0.92, bottom=0.13, wspace=0.25)
    return _png(fig)


def _surface_source(diag: Any) -> tuple[Any, str]:
    """The error surface that belongs to the reported S and J, and the fit it comes from."""
    ident = diag.identification
    if diag.result.get("method") == "op_mv" and getattr(ident, "valve_fit", None) is not None:
        return getattr(ident.valve_fit, "surface", None), "OP-MV valve fit"
    fit = getattr(ident, "fit", None)
    return (getattr(fit, "surface", None) if fit is not None else None), "OP-PV Hammerstein fit"


def surface(diag: Any) -> bytes | None:
    """The (S, J) error surface of the fit that gave S and J, with the estimate and its intervals."""
    surf, source = _surface_source(diag)
    if surf is None:
        return None
    S_grid = np.asarray(surf.S_grid_pct, dtype=float)
    J_grid = np.asarray(surf.J_grid_pct, dtype=float)
    cost = np.asarray(surf.cost, dtype=float)
    if cost.ndim != 2 or cost.size == 0:
        return None
    if cost.shape != (S_grid.size, J_grid.size) and cost.shape == (J_grid.size, S_grid.size):
        cost = cost.T
    if cost.shape != (S_grid.size, J_grid.size):
        return None
    fig = _figure(4.6, 3.8)
    ax = fig.subplots()
    finite = np.isfinite(cost)
    z = np.where(finite, cost, np.nan)
    if np.any(finite):
        lo = np.nanmin(z)
        z = np.log10(np.maximum(z - lo, 0) + max(abs(lo), 1e-12) * 1e-3 + 1e-12)
    if S_grid.size > 1 and J_grid.size > 1:
        cs = ax.contourf(S_grid, J_grid, z.T, levels=14, cmap="viridis")
        cb = fig.colorbar(cs, ax=ax)
        cb.set_label("log10 excess cost", fontsize=7)
        cb.ax.tick_params(labelsize=7)
    res = diag.result
    S, J = res.get("S"), res.get("J")
    if S is not None and J is not None:
        from .pipeline import _interval

        slo, shi = _interval(res.get("S_interval"))
        jlo, jhi = _interval(res.get("J_interval"))
        xerr = None if slo is None or shi is None else [[max(S - slo, 0)], [max(shi - S, 0)]]
        yerr = None if jlo is None or jhi is None else [[max(J - jlo, 0)], [max(jhi - J, 0)]]
        ax.errorbar([S], [J], xerr=xerr, yerr=yerr, fmt="o", color="white", mec="black", ms=6,
                    ecolor="white", capsize=3, label="estimate")
    hi = max(float(S_grid.max()), float(J_grid.max())) if S_grid.size and J_grid.size else 1.0
    ax.plot([0, hi], [0, hi], ls="--", lw=0.8, color="#d62728", label="J = S")
    ax.set_xlim(float(S_grid.min()), float(S_grid.max()))
    ax.set_ylim(float(J_grid.min()), float(J_grid.max()))
    ax.set_xlabel("S (% of span)")
    ax.set_ylabel("J (% of span)")
    ax.set_title(f"error surface of the {source}", fontsize=9)
    ax.legend(loc="upper left", fontsize=7)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.92, bottom=0.13)
    return _png(fig)


def narx(diag: Any) -> bytes | None:
    """The selected NARX-SP model's free run against the record (MV if recorded, else PV)."""
    if diag.narx_mv_hat_pct is None:
        return None
    rec = diag.record
    t, tlabel = _time_axis(rec)
    fig = _figure(8.0, 2.8)
    ax = fig.subplots()
    if rec.mv is not None:
        _plot(ax, t, rec.mv, color=COLORS["mv"], label="recorded MV")
        _plot(ax, t, diag.narx_mv_hat_pct, color=COLORS["narx"], label="NARX-SP free run (MV)")
        ax.set_ylim(*record_limits(rec.mv))
        ax.set_ylabel("MV (% of span)")
    elif diag.narx_pv_hat is not None:
        _plot(ax, t, rec.pv, color=COLORS["pv"], label="recorded PV")
        _plot(ax, t, diag.narx_pv_hat, color=COLORS["narx"], label="NARX-SP valve + process model")
        ax.set_ylim(*record_limits(rec.pv))
        ax.set_ylabel("PV")
    else:
        _plot(ax, t, rec.op, color=COLORS["op"], label="OP")
        _plot(ax, t, diag.narx_mv_hat_pct, color=COLORS["narx"], label="NARX-SP free run (MV)")
        ax.set_ylim(*record_limits(rec.op))
        ax.set_ylabel("% of span")
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax.set_xlabel(tlabel)
    ax.legend(loc="upper right", fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.95, bottom=0.17)
    return _png(fig)


def pv_spectrum(pv: np.ndarray, ts_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Periods (s) and power of the detrended PV (frequency 0 left out)."""
    x = np.asarray(pv, dtype=float)
    n = x.shape[0]
    k = np.arange(n)
    x = x - np.polyval(np.polyfit(k, x, 1), k) if n > 2 else x - x.mean()
    win = np.hanning(n)
    p = np.abs(np.fft.rfft(x * win)) ** 2
    f = np.fft.rfftfreq(n, ts_s)
    return 1.0 / f[1:], p[1:]


#: Tick marks of a period axis, in seconds: 1 s to a week at round durations.
_PERIOD_TICKS_S = (1, 2, 5, 10, 20, 30, 60, 120, 300, 600, 1200, 1800, 3600, 2 * 3600, 6 * 3600,
                   12 * 3600, 86400, 2 * 86400, 7 * 86400)


def _period_axis(ax: Any, lo_s: float, hi_s: float) -> None:
    """Label a log period axis in round seconds, minutes, hours and days (no exponents)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    from ..plain import duration

    ticks = [v for v in _PERIOD_TICKS_S if lo_s <= v <= hi_s]
    while len(ticks) > 7:
        ticks = ticks[::2]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: duration(v)))
    ax.tick_params(axis="x", labelsize=7)


def spectrum(diag: Any) -> bytes:
    """PV power against period; the oscillation's period is marked only where the result says the
    loop oscillates (the spectrum of any record has a highest peak)."""
    rec = diag.record
    period, power = pv_spectrum(rec.pv, rec.ts_s)
    fig = _figure(4.6, 3.0)
    ax = fig.subplots()
    ax.loglog(period, power + 1e-30, lw=0.7, color=COLORS["pv"])
    from .pipeline import oscillation_info
    from ..plain import duration

    osc = oscillation_info(diag.result)
    if osc["present"] and osc["period_s"]:
        ax.axvline(osc["period_s"], color=COLORS["op"], ls="--", lw=1.0,
                   label=f"oscillation period {duration(osc['period_s'])}")
        ax.legend(loc="best", fontsize=7)
    ax.set_xlabel("period")
    ax.set_ylabel("PV power")
    if period.size:
        _period_axis(ax, float(period.min()), float(period.max()))
    ax.invert_xaxis()
    fig.subplots_adjust(left=0.15, right=0.97, top=0.95, bottom=0.16)
    return _png(fig)


def explanation(diag: Any) -> bytes | None:
    """The missing-physics figure, drawn by `diagnose.physics.figures` when that exists."""
    if diag.explanation is None:
        return None
    try:
        from ..physics import figures as pfig  # type: ignore[attr-defined]
    except ImportError:
        return None
    expl = diag.explanation
    if hasattr(pfig, "draw_explanation") and hasattr(expl, "figure_data"):
        title = f"{diag.record.name}: missing physics: {getattr(expl, 'missing_physics', None) or 'none named'}"
        fig = pfig.draw_explanation(expl.figure_data(), title=title, figsize=(8.0, 6.5))
        try:
            buf = io.BytesIO()
            fig.savefig(buf, format="png", dpi=DPI)
            return buf.getvalue()
        finally:
            import matplotlib.pyplot as plt

            plt.close(fig)
    if hasattr(pfig, "plot_explanation"):
        import tempfile
        from pathlib import Path

        with tempfile.TemporaryDirectory() as tmp:
            path = pfig.plot_explanation(expl, diag.record, path_png=Path(tmp) / "explanation.png", dpi=DPI)
            return Path(path).read_bytes()
    return None


def history(rows: list[Mapping[str, Any]]) -> bytes | None:
    """S and J record over record (from the history database), labelled by each record's end."""
    pts = [(r.get("data_end") or r.get("run_at", ""), r.get("S_pct"), r.get("J_pct"))
           for r in rows if r.get("S_pct") is not None]
    if len(pts) < 2:
        return None
    fig = _figure(4.6, 2.6)
    ax = fig.subplots()
    x = np.arange(len(pts))
    ax.plot(x, [p[1] for p in pts], "o-", color=COLORS["op"], label="S")
    ax.plot(x, [p[2] if p[2] is not None else np.nan for p in pts], "s-", color=COLORS["mv"], label="J")
    ax.set_xticks(x)
    ax.set_xticklabels([str(p[0])[:10] for p in pts], rotation=30, fontsize=6, ha="right")
    ax.set_ylabel("% of span")
    ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.13, right=0.97, top=0.95, bottom=0.27)
    return _png(fig)


def loop_figures(diag: Any, history_rows: list[Mapping[str, Any]] | None = None) -> dict[str, bytes]:
    """All figures of one loop's report as ``{name: png_bytes}`` (absent figures left out)."""
    mv_hat, pv_hat = _model_path(diag)
    out: dict[str, bytes | None] = {
        "trends": trends(diag, mv_hat, pv_hat),
        "phase": phase(diag, mv_hat, pv_hat),
        "surface": surface(diag),
        "narx": narx(diag),
        "spectrum": spectrum(diag),
    }
    try:
        out["explanation"] = explanation(diag)
    except Exception:  # a broken optional figure must not sink the report
        out["explanation"] = None
    if history_rows:
        out["history"] = history(history_rows)
    return {k: v for k, v in out.items() if v is not None}
