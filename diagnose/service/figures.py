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
    """Reduce a long series to at most ``2 * max_points`` points keeping each bucket's min and max.

    The oscillation's amplitude and shape survive (a plain stride would alias it away).
    """
    n = y.shape[0]
    if n <= 2 * max_points:
        return t, y
    m = n // max_points
    k = m * max_points
    yb = y[:k].reshape(max_points, m)
    tb = t[:k].reshape(max_points, m)
    lo_i = np.argmin(yb, axis=1)
    hi_i = np.argmax(yb, axis=1)
    first = np.minimum(lo_i, hi_i)
    second = np.maximum(lo_i, hi_i)
    rows = np.arange(max_points)
    tt = np.empty(2 * max_points)
    yy = np.empty(2 * max_points)
    tt[0::2], tt[1::2] = tb[rows, first], tb[rows, second]
    yy[0::2], yy[1::2] = yb[rows, first], yb[rows, second]
    return tt, yy


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
    ax.plot(tt, yy, lw=0.8, **kw)


def _model_path(diag: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fitted Hammerstein model's (MV, PV) over the whole record, if a fit exists."""
    fit = getattr(diag.identification, "fit", None)
    if fit is None:
        return None, None
    try:
        mv_hat, pv_hat = fit.simulate(diag.record.op)
    except Exception:
        return None, None
    return np.asarray(mv_hat, dtype=float), np.asarray(pv_hat, dtype=float)


def trends(diag: Any, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    rec = diag.record
    t, tlabel = _time_axis(rec)
    fig = _figure(8.0, 4.6)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if rec.sp is not None:
        _plot(ax1, t, rec.sp, color=COLORS["sp"], label="SP")
    _plot(ax1, t, rec.pv, color=COLORS["pv"], label="PV")
    if pv_hat is not None:
        _plot(ax1, t, pv_hat, color=COLORS["model"], label="model PV", alpha=0.8)
    unit = rec.units.get("pv", "")
    ax1.set_ylabel(f"PV{' (' + unit + ')' if unit else ''}")
    ax1.legend(loc="upper right", fontsize=7, ncol=3)
    _plot(ax2, t, rec.op, color=COLORS["op"], label="OP")
    if rec.mv is not None:
        _plot(ax2, t, rec.mv, color=COLORS["mv"], label="MV")
    if mv_hat is not None:
        _plot(ax2, t, mv_hat, color=COLORS["model"], label="model MV", alpha=0.8)
    ax2.set_ylabel("% of span")
    ax2.set_xlabel(tlabel)
    ax2.legend(loc="upper right", fontsize=7, ncol=3)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.97, bottom=0.11, hspace=0.08)
    return _png(fig)


def phase(diag: Any, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    """OP-PV (and OP-MV where the record has MV) with the fitted model's path over it."""
    rec = diag.record
    two = rec.mv is not None
    fig = _figure(8.0 if two else 4.6, 3.8)
    axes = fig.subplots(1, 2 if two else 1, squeeze=False)[0]
    s = slice(max(rec.n - PHASE_SAMPLES, 0), None)  # the last part: whole cycles stay legible
    ax = axes[0]
    ax.plot(rec.op[s], rec.pv[s], lw=0.5, color=COLORS["pv"], label="record")
    if pv_hat is not None:
        ax.plot(rec.op[s], pv_hat[s], lw=0.9, color=COLORS["model"], label="fitted model")
    ax.set_xlabel("OP (%)")
    ax.set_ylabel("PV")
    ax.set_title(f"OP-PV, last {min(rec.n, PHASE_SAMPLES)} samples", fontsize=9)
    ax.legend(loc="best", fontsize=7)
    if two:
        ax = axes[1]
        ax.plot(rec.op[s], rec.mv[s], lw=0.5, color=COLORS["mv"], label="record")
        if mv_hat is not None:
            ax.plot(rec.op[s], mv_hat[s], lw=0.9, color=COLORS["model"], label="fitted valve")
        ax.set_xlabel("OP (%)")
        ax.set_ylabel("MV (%)")
        ax.set_title(f"OP-MV, last {min(rec.n, PHASE_SAMPLES)} samples", fontsize=9)
        ax.legend(loc="best", fontsize=7)
    fig.subplots_adjust(left=0.15 if not two else 0.09, right=0.98, top=0.92, bottom=0.13, wspace=0.25)
    return _png(fig)


def surface(diag: Any) -> bytes | None:
    """The (S, J) error surface of the Hammerstein fit with the estimate and its intervals."""
    fit = getattr(diag.identification, "fit", None)
    surf = getattr(fit, "surface", None) if fit is not None else None
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
    ax.legend(loc="upper left", fontsize=7)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.96, bottom=0.13)
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
        ax.set_ylabel("MV (% of span)")
    elif diag.narx_pv_hat is not None:
        _plot(ax, t, rec.pv, color=COLORS["pv"], label="recorded PV")
        _plot(ax, t, diag.narx_pv_hat, color=COLORS["narx"], label="NARX-SP valve + process model")
        ax.set_ylabel("PV")
    else:
        _plot(ax, t, rec.op, color=COLORS["op"], label="OP")
        _plot(ax, t, diag.narx_mv_hat_pct, color=COLORS["narx"], label="NARX-SP free run (MV)")
        ax.set_ylabel("% of span")
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


def spectrum(diag: Any) -> bytes:
    rec = diag.record
    period, power = pv_spectrum(rec.pv, rec.ts_s)
    fig = _figure(4.6, 3.0)
    ax = fig.subplots()
    ax.loglog(period, power + 1e-30, lw=0.7, color=COLORS["pv"])
    from .pipeline import oscillation_info

    osc = oscillation_info(diag.result)
    if osc["period_s"]:
        ax.axvline(osc["period_s"], color=COLORS["op"], ls="--", lw=1.0,
                   label=f"oscillation period {osc['period_s']:.0f} s")
        ax.legend(loc="best", fontsize=7)
    ax.set_xlabel("period (s)")
    ax.set_ylabel("PV power")
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
    """S and J run over run (from the history database)."""
    pts = [(r.get("run_at", ""), r.get("S_pct"), r.get("J_pct")) for r in rows if r.get("S_pct") is not None]
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
