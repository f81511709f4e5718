"""The figures of an identification: trends, phase plots, error surface, NARX-SP free run, spectrum.

Each ``draw_*`` function draws on a matplotlib `Figure` it is given (the object API, no pyplot and
no global state), so the same drawing serves a notebook (`Identification.plot` returns a new
figure) and the reports (`diagnose.service.figures` draws on reused Agg figures and writes PNG).
matplotlib is imported only when a figure is made. Long series are reduced to a min/max envelope
before drawing; every trend reaches the record's last sample.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .fit import ErrorSurface
    from .identification import Identification
    from .record import LoopRecord

#: Longest series drawn as is; longer ones become a min/max envelope of this many buckets.
MAX_POINTS = 1200
#: The phase plots show the last this many samples (a whole long record is an unreadable tangle).
PHASE_SAMPLES = 1000
#: Figure sizes (inches) of each kind.
SIZES = {"trends": (8.0, 4.6), "phase": (8.0, 3.8), "phase_op_pv": (4.6, 3.8), "surface": (4.6, 3.8),
         "narx": (8.0, 2.8), "spectrum": (4.6, 3.0)}

COLORS = {"pv": "#1f77b4", "sp": "#555555", "op": "#d62728", "mv": "#2ca02c", "model": "#ff7f0e",
          "narx": "#9467bd"}


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


def time_axis(record: LoopRecord) -> tuple[np.ndarray, str]:
    """Sample times in the unit that suits the record's length, and the axis label."""
    t = record.t_s
    dur = record.duration_s
    if dur > 4 * 3600:
        return t / 3600.0, "time (h)"
    if dur > 600:
        return t / 60.0, "time (min)"
    return t, "time (s)"


def _plot(ax: Axes, t: np.ndarray, y: np.ndarray, **kw: Any) -> None:
    tt, yy = envelope(t, y)
    ax.plot(tt, yy, lw=kw.pop("lw", 0.8), **kw)


#: Share of a model line's samples kept inside the axis at each end (`record_limits`).
MODEL_TAIL = 0.05


def record_limits(*series: np.ndarray | None, margin: float = 0.08,
                  models: tuple[np.ndarray | None, ...] = ()) -> tuple[float, float]:
    """Axis range of recorded series, padded by ``margin`` of their span.

    Model lines (``models``) widen it to their 5th-95th percentile only: a simulation started
    from the wrong state can swing far off in its first samples, and that start-up transient must
    not set the scale, but a model that runs beside the record, or off it, must stay in view.
    """
    vals = [np.asarray(v, dtype=float) for v in series if v is not None]
    vals = [v[np.isfinite(v)] for v in vals]
    for m in models:
        m = np.asarray(m, dtype=float) if m is not None else np.zeros(0)
        m = m[np.isfinite(m)]
        if m.size:
            vals.append(np.percentile(m, [100 * MODEL_TAIL, 100 * (1 - MODEL_TAIL)]))
    vals = [v for v in vals if v.size]
    if not vals:
        return 0.0, 1.0
    lo = min(float(v.min()) for v in vals)
    hi = max(float(v.max()) for v in vals)
    span = hi - lo
    if span <= 0:
        span = max(abs(hi), 1.0) * 0.1
    return lo - margin * span, hi + margin * span


def _pv_label(record: LoopRecord) -> str:
    unit = record.units.get("pv", "")
    return f"PV ({unit})" if unit else "PV"


def span_label(op_units: str = "% of span") -> str:
    """An axis's unit for OP and the valve path (`Identification.op_units`): a fraction of span,
    or OP's own units where its span is unknown, is said as such."""
    return {"OP units": "OP's own units"}.get(op_units, op_units)


def draw_trends(fig: Figure, record: LoopRecord, mv_hat: np.ndarray | None = None,
                pv_hat: np.ndarray | None = None, *, op_units: str = "% of span") -> Figure:
    """SP and PV over OP (and MV), the whole record, the model's PV and valve path beneath them;
    ``op_units`` is OP's (`Identification.op_units`)."""
    t, tlabel = time_axis(record)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    if pv_hat is not None:
        _plot(ax1, t, pv_hat, color=COLORS["model"], label="model PV", alpha=0.8, zorder=1)
    if record.sp is not None:
        _plot(ax1, t, record.sp, color=COLORS["sp"], label="SP", zorder=2)
    _plot(ax1, t, record.pv, color=COLORS["pv"], label="PV", zorder=3)
    ax1.set_ylim(*record_limits(record.pv, record.sp, models=(pv_hat,)))
    ax1.set_ylabel(_pv_label(record))
    ax1.legend(loc="upper right", fontsize=7, ncol=3)
    if mv_hat is not None:
        _plot(ax2, t, mv_hat, color=COLORS["model"], label="model valve", alpha=0.8, zorder=1)
    _plot(ax2, t, record.op, color=COLORS["op"], label="OP", zorder=2)
    if record.mv is not None:
        _plot(ax2, t, record.mv, color=COLORS["mv"], label="MV", zorder=3)
    ax2.set_ylim(*record_limits(record.op, record.mv, models=(mv_hat,)))
    ax2.set_ylabel(span_label(op_units))
    ax2.set_xlabel(tlabel)
    ax2.set_xlim(float(t[0]), float(t[-1]))
    ax2.legend(loc="upper right", fontsize=7, ncol=3)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.97, bottom=0.11, hspace=0.08)
    return fig


def draw_phase(fig: Figure, record: LoopRecord, mv_hat: np.ndarray | None = None,
               pv_hat: np.ndarray | None = None, *, op_units: str = "% of span") -> Figure:
    """OP-PV (and OP-MV where the record has MV), the fitted model's path dashed beneath it;
    ``op_units`` is OP's (`Identification.op_units`)."""
    two = record.mv is not None
    axes = fig.subplots(1, 2 if two else 1, squeeze=False)[0]
    s = slice(max(record.n - PHASE_SAMPLES, 0), None)  # the last part: whole cycles stay legible
    shown = min(record.n, PHASE_SAMPLES)
    op = record.op[s]
    panels = [(record.pv, pv_hat, "fitted model", COLORS["pv"], _pv_label(record), "OP-PV")]
    if two:
        panels.append((record.mv, mv_hat, "fitted valve", COLORS["mv"], "MV (% of span)", "OP-MV"))
    for ax, (y, y_hat, model_label, color, ylabel, name) in zip(axes, panels):
        if y_hat is not None:
            ax.plot(op, y_hat[s], lw=1.0, ls="--", color=COLORS["model"], label=model_label, zorder=1)
        ax.plot(op, y[s], lw=0.8, color=color, label="record", zorder=2)
        ax.set_xlim(*record_limits(op))
        ax.set_ylim(*record_limits(y[s]))
        ax.set_xlabel(f"OP ({span_label(op_units)})")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{name}, last {shown} samples", fontsize=9)
        ax.legend(loc="best", fontsize=7)
    fig.subplots_adjust(left=0.15 if not two else 0.11, right=0.98, top=0.92, bottom=0.13, wspace=0.3)
    return fig


def surface_source(ident: Identification) -> tuple[ErrorSurface | None, str]:
    """The error surface that belongs to the reported S and J, and the fit it comes from."""
    if ident.method == "op_mv" and ident.valve_fit is not None:
        return ident.valve_fit.surface, "OP-MV valve fit"
    return (ident.fit.surface if ident.fit is not None else None), "OP-PV Hammerstein fit"


def draw_surface(fig: Figure, ident: Identification) -> bool:
    """The (S, J) error surface of the fit that gave S and J, with the estimate and its intervals.
    False (nothing drawn) when there is no usable surface."""
    surf, source = surface_source(ident)
    if surf is None:
        return False
    S_grid = np.asarray(surf.S_grid_pct, dtype=float)
    J_grid = np.asarray(surf.J_grid_pct, dtype=float)
    cost = np.asarray(surf.cost, dtype=float)
    if cost.ndim != 2 or cost.size == 0:
        return False
    if cost.shape != (S_grid.size, J_grid.size) and cost.shape == (J_grid.size, S_grid.size):
        cost = cost.T
    if cost.shape != (S_grid.size, J_grid.size):
        return False
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
    S, J = ident.S_pct, ident.J_pct
    if S is not None and J is not None:
        si, ji = ident.S_interval_pct, ident.J_interval_pct
        xerr = None if si is None else [[max(S - si[0], 0)], [max(si[1] - S, 0)]]
        yerr = None if ji is None else [[max(J - ji[0], 0)], [max(ji[1] - J, 0)]]
        ax.errorbar([S], [J], xerr=xerr, yerr=yerr, fmt="o", color="white", mec="black", ms=6,
                    ecolor="white", capsize=3, label="estimate")
    hi = max(float(S_grid.max()), float(J_grid.max())) if S_grid.size and J_grid.size else 1.0
    ax.plot([0, hi], [0, hi], ls="--", lw=0.8, color="#d62728", label="J = S")
    ax.set_xlim(float(S_grid.min()), float(S_grid.max()))
    ax.set_ylim(float(J_grid.min()), float(J_grid.max()))
    ax.set_xlabel(f"S ({span_label(ident.op_units)})")
    ax.set_ylabel(f"J ({span_label(ident.op_units)})")
    ax.set_title(f"error surface of the {source}", fontsize=9)
    ax.legend(loc="upper left", fontsize=7)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.92, bottom=0.13)
    return True


def draw_narx(fig: Figure, record: LoopRecord, mv_hat_pct: np.ndarray, pv_hat: np.ndarray | None = None, *,
              op_units: str = "% of span") -> Figure:
    """A NARX-SP free run against the record: MV where recorded, else PV through the process model
    (else OP and the free run, in OP's units ``op_units``)."""
    t, tlabel = time_axis(record)
    ax = fig.subplots()
    if record.mv is not None:
        _plot(ax, t, record.mv, color=COLORS["mv"], label="recorded MV")
        _plot(ax, t, mv_hat_pct, color=COLORS["narx"], label="NARX-SP free run (MV)")
        ax.set_ylim(*record_limits(record.mv, models=(mv_hat_pct,)))
        ax.set_ylabel("MV (% of span)")
    elif pv_hat is not None:
        _plot(ax, t, record.pv, color=COLORS["pv"], label="recorded PV")
        _plot(ax, t, pv_hat, color=COLORS["narx"], label="NARX-SP valve + process model")
        ax.set_ylim(*record_limits(record.pv, models=(pv_hat,)))
        ax.set_ylabel(_pv_label(record))
    else:
        _plot(ax, t, record.op, color=COLORS["op"], label="OP")
        _plot(ax, t, mv_hat_pct, color=COLORS["narx"], label="NARX-SP free run (MV)")
        ax.set_ylim(*record_limits(record.op, models=(mv_hat_pct,)))
        ax.set_ylabel(span_label(op_units))
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax.set_xlabel(tlabel)
    ax.legend(loc="upper right", fontsize=7, ncol=2)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.95, bottom=0.17)
    return fig


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


def period_axis(ax: Axes, lo_s: float, hi_s: float) -> None:
    """Label a log period axis in round seconds, minutes, hours and days (no exponents)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullLocator

    from .plain import duration

    ticks = [v for v in _PERIOD_TICKS_S if lo_s <= v <= hi_s]
    while len(ticks) > 7:
        ticks = ticks[::2]
    ax.xaxis.set_major_locator(FixedLocator(ticks))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: duration(v)))
    ax.tick_params(axis="x", labelsize=7)


def draw_spectrum(fig: Figure, record: LoopRecord, period_s: float | None = None) -> Figure:
    """PV power against period; ``period_s`` (a loop oscillation's period) is marked when given.

    Only a period the verdict calls an oscillation should be given: the spectrum of any record
    has a highest peak.
    """
    from .plain import duration

    period, power = pv_spectrum(record.pv, record.ts_s)
    ax = fig.subplots()
    ax.loglog(period, power + 1e-30, lw=0.7, color=COLORS["pv"])
    if period_s:
        ax.axvline(period_s, color=COLORS["op"], ls="--", lw=1.0, label=f"oscillation period {duration(period_s)}")
        ax.legend(loc="best", fontsize=7)
    ax.set_xlabel("period")
    ax.set_ylabel("PV power")
    if period.size:
        period_axis(ax, float(period.min()), float(period.max()))
    ax.invert_xaxis()
    fig.subplots_adjust(left=0.15, right=0.97, top=0.95, bottom=0.16)
    return fig


def marked_period(ident: Identification) -> float | None:
    """The period the spectrum marks: the loop's oscillation, not a slow cycle or a mere peak."""
    return ident.oscillation.period_s if ident.loop_oscillates else None


def new_figure(kind: str, record: LoopRecord | None = None) -> Figure:
    """A new matplotlib `Figure` (no pyplot, so nothing global) of the size of this kind."""
    from matplotlib.figure import Figure

    size = SIZES["phase_op_pv"] if kind == "phase" and record is not None and record.mv is None else SIZES[kind]
    return Figure(figsize=size, dpi=100)


def plot_identification(ident: Identification, kind: str = "trends") -> Figure:
    """One of the report's figures of an identification (which carries its record), as a new Figure."""
    from .errors import DataError

    rec = ident.record
    if rec is None:
        raise DataError("this identification carries no record to plot")
    if kind not in ("trends", "phase", "surface", "spectrum"):
        raise DataError(f"unknown figure {kind!r}; use trends, phase, surface or spectrum")
    fig = new_figure(kind, rec)
    if kind == "surface":
        if not draw_surface(fig, ident):
            raise DataError(f"{ident.loop}: no error surface (no model was fitted)")
        return fig
    if kind == "spectrum":
        return draw_spectrum(fig, rec, marked_period(ident))
    mv_hat, pv_hat = ident.model_path()
    return (draw_trends if kind == "trends" else draw_phase)(fig, rec, mv_hat, pv_hat, op_units=ident.op_units)
