"""Report figures as PNG bytes: trends, phase plots, error surface, NARX-SP free run, spectrum,
missing physics, history.

The drawing is `diagnose.figures` (the same figures `Identification.plot` returns in a notebook);
this module draws them for the reports, lean on purpose (a nightly batch draws thousands): the
Agg canvas, one reusable `Figure` per size per process (cleared, not rebuilt), low dpi.
matplotlib is imported only when a figure is drawn. Functions return PNG bytes; the caller decides
where files go.
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from .. import figures as draw
from ..figures import COLORS, SIZES

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..fit import ErrorSurface
    from .pipeline import Diagnosis

DPI = 72
_FIGS: dict[tuple[float, float], Figure] = {}


def _figure(w_in: float, h_in: float) -> Figure:
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


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    # fast zlib level: somewhat larger files for much faster encoding (a batch draws many figures)
    fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": 1})
    return buf.getvalue()


def _model_path(diag: Diagnosis) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The fitted model's (valve path, PV) over the whole record, as the report draws them
    (`Identification.model_path`)."""
    return diag.identification.model_path(diag.record.op)


def _surface_source(diag: Diagnosis) -> tuple[ErrorSurface | None, str]:
    return draw.surface_source(diag.identification)


def trends(diag: Diagnosis, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    return _png(draw.draw_trends(_figure(*SIZES["trends"]), diag.record, mv_hat, pv_hat,
                                 op_units=diag.identification.op_units))


def phase(diag: Diagnosis, mv_hat: np.ndarray | None = None, pv_hat: np.ndarray | None = None) -> bytes:
    size = SIZES["phase"] if diag.record.mv is not None else SIZES["phase_op_pv"]
    return _png(draw.draw_phase(_figure(*size), diag.record, mv_hat, pv_hat, op_units=diag.identification.op_units))


def surface(diag: Diagnosis) -> bytes | None:
    fig = _figure(*SIZES["surface"])
    return _png(fig) if draw.draw_surface(fig, diag.identification) else None


def narx(diag: Diagnosis) -> bytes | None:
    if diag.narx_mv_hat_pct is None:
        return None
    return _png(draw.draw_narx(_figure(*SIZES["narx"]), diag.record, diag.narx_mv_hat_pct, diag.narx_pv_hat,
                               op_units=diag.identification.op_units))


def spectrum(diag: Diagnosis) -> bytes:
    fig = _figure(*SIZES["spectrum"])
    return _png(draw.draw_spectrum(fig, diag.record, draw.marked_period(diag.identification)))


def explanation(diag: Diagnosis) -> bytes | None:
    """The missing-physics figure of a diagnosis (None when it has no explanation)."""
    if diag.explanation is None:
        return None
    return explanation_png(diag.explanation, diag.record.name)


def explanation_png(explanation: Any, loop: str = "", *, dpi: float = DPI) -> bytes:
    """The missing-physics figure of an `Explanation` (drawn by `diagnose.physics.figures`) as PNG
    bytes; ``loop`` names the loop in the title."""
    from ..physics.figures import draw_explanation

    title = f"{loop + ': ' if loop else ''}missing physics: {explanation.missing_physics or 'none named'}"
    fig = draw_explanation(explanation.figure_data(), title=title, figsize=(8.0, 6.5))
    try:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        return buf.getvalue()
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


def history(rows: list[Mapping[str, Any]]) -> bytes | None:
    """S and J record over record (history database rows), labelled by each record's end. A run
    that said no stiction has no size (`history.shown_run`): a gap, so the time axis keeps it."""
    from .history import run_units, shown_run, size_pct

    stored = [r for r in rows if r.get("S_pct") is not None]
    shown = [shown_run(r) for r in stored]
    units = {run_units(r) for r in shown}
    if len(units) == 1:     # the runs' own units, as the tables give them
        (unit,) = units
        pts = [(r.get("data_end") or r.get("run_at", ""), r.get("S_pct"), r.get("J_pct")) for r in shown]
        label = unit
    else:                   # runs in other units (a tag map added later): in % of span where known
        pts = [(r.get("data_end") or r.get("run_at", ""), size_pct(r), size_pct(r, "J_pct")) for r in shown]
        label = "% of span" if "OP units" not in units else "% of span (OP units where not known)"
    if sum(p[1] is not None for p in pts) < 2:
        return None
    fig = _figure(4.6, 2.6)
    ax = fig.subplots()
    x = np.arange(len(pts))
    ax.plot(x, [p[1] if p[1] is not None else np.nan for p in pts], "o-", color=COLORS["op"], label="S")
    ax.plot(x, [p[2] if p[2] is not None else np.nan for p in pts], "s-", color=COLORS["mv"], label="J")
    ax.set_xticks(x)
    # the day where it tells the records apart, else the time of day too (hourly windows)
    days = [str(p[0])[:10] for p in pts]
    ticks = days if len(set(days)) == len(days) else [str(p[0])[:16].replace("T", " ") for p in pts]
    ax.set_xticklabels(ticks, rotation=30, fontsize=6, ha="right")
    ax.set_xlabel("record end (UTC)", fontsize=7)
    ax.set_ylabel(label)
    ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.13, right=0.97, top=0.95, bottom=0.33)
    return _png(fig)


def loop_figures(diag: Diagnosis, history_rows: list[Mapping[str, Any]] | None = None) -> dict[str, bytes]:
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
