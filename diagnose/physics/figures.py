"""Figures of an `Explanation`: the fits, the residual with the located windows, and the
conditioned residuals. matplotlib is imported only here and only when a figure is drawn (Agg).

The computation lives in `Explanation.figure_data`; this module only draws it and returns the
matplotlib figure (writing it anywhere is the caller's: `fig.savefig(...)`, or the service's
`diagnose.service.figures.explanation_png`).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _time_unit(span_s: float) -> tuple[float, str]:
    """Divisor and unit name for a time axis of this span (hours, minutes or seconds)."""
    if span_s > 4 * 3600:
        return 3600.0, "h"
    if span_s > 600:
        return 60.0, "min"
    return 1.0, "s"


def _distinct_labels(values) -> list[str]:
    """Tick labels with the fewest decimals (up to 2) that tell every value apart."""
    vals = [float(v) for v in values]
    for dec in range(3):
        labels = [f"{v:.{dec}f}" for v in vals]
        if len(set(labels)) == len(labels):
            return labels
    return labels


def draw_explanation(fig_data: dict[str, Any], *, title: str = "", figsize=(11.0, 9.0)):
    """Draw the figure data onto a new matplotlib figure and return it."""
    plt = _mpl()
    d = dict(fig_data)
    # times in the unit the record's length calls for (a week of data is not read in seconds)
    div, tu = _time_unit(float(np.ptp(np.asarray(d["t_s"]))) if len(d["t_s"]) else 0.0)
    t = np.asarray(d["t_s"]) / div
    for key in ("train_end_s", "train_start_s"):
        if d.get(key) is not None:
            d[key] = float(d[key]) / div
    d["windows"] = [(a / div, b / div) for a, b in d.get("windows", [])]
    d["window_t_s"] = np.asarray(d["window_t_s"]) / div
    d["slip_t_s"] = np.asarray(d.get("slip_t_s", [])) / div
    lag_div, lag_u = _time_unit(float(np.max(d["profile_lag_s"])) if len(d["profile_lag_s"]) else 0.0)
    fig = plt.figure(figsize=figsize, constrained_layout=True)
    gs = fig.add_gridspec(3, 3)
    unit = d.get("units", "")
    name = d.get("missing_physics") or "none named"

    ax = fig.add_subplot(gs[0, :])
    ax.plot(t, d["observed"], color="0.3", lw=0.8, label="recorded")
    ax.plot(t, d["baseline"], color="tab:red", lw=0.8, label="baseline (fitting stage)")
    if "reference" in d:
        ax.plot(t, d["reference"], color="tab:orange", lw=0.8, ls="--", label="plain model refit")
    if d.get("missing_physics"):
        ax.plot(t, d["improved"], color="tab:blue", lw=0.8, label=f"with {name}")
    ax.axvline(d["train_end_s"], color="k", ls="--", lw=0.8)
    ax.text(d["train_end_s"], ax.get_ylim()[1], " held out ->", va="top", fontsize=8)
    if d.get("train_start_s", 0.0) > 0:
        ax.axvspan(0.0, d["train_start_s"], color="0.85", alpha=0.5, lw=0)
        ax.text(0.0, ax.get_ylim()[1], " not scored (initial state)", va="top", fontsize=7)
    ax.set_ylabel(f"{d.get('target', 'pv').upper()} [{unit}]")
    ax.set_title(title or f"missing physics: {name}")
    ax.legend(loc="lower left", fontsize=8, ncol=4)

    ax = fig.add_subplot(gs[1, :])
    ax.plot(t, d.get("residual_located", d["residual_baseline"]), color="tab:red", lw=0.6,
            label=f"{d.get('located_on', 'baseline')} residual")
    if d.get("missing_physics"):
        ax.plot(t, d["residual_improved"], color="tab:blue", lw=0.6, label="improved residual")
    for a, b in d.get("windows", []):
        ax.axvspan(a, b, color="orange", alpha=0.25)
    ax.plot(d["window_t_s"], d["window_rms"], color="k", lw=1.2, label="window RMS")
    slips = np.asarray(d.get("slip_t_s", []))
    if slips.size:
        lo = ax.get_ylim()[0]
        ax.plot(slips, np.full(slips.shape, lo), "|", color="tab:green", ms=6, label="simulated slips")
    ax.axvline(d["train_end_s"], color="k", ls="--", lw=0.8)
    ax.set_xlabel(f"time [{tu}]")
    ax.set_ylabel(f"residual [{unit}]")
    ax.legend(loc="upper left", fontsize=8, ncol=4)

    ax = fig.add_subplot(gs[2, 0])
    ax.plot(np.asarray(d["profile_lag_s"]) / lag_div, d["after_slip_profile"], "o-", ms=3)
    ax.axhline(float(np.sqrt(np.mean(np.square(d.get("residual_located", d["residual_baseline"]))))), color="0.5", ls=":",
               label="overall RMS")
    ax.set_xlabel(f"time after a slip [{lag_u}]")
    ax.set_ylabel("residual RMS")
    ax.set_title("residual after slips", fontsize=9)
    ax.legend(fontsize=7)

    ax = fig.add_subplot(gs[2, 1])
    ax.bar(np.arange(len(d["op_bin_rms"])), d["op_bin_rms"], color="tab:purple", alpha=0.7)
    ax.set_xticks(np.arange(len(d["op_bin_rms"])))
    ax.set_xticklabels(_distinct_labels(d["op_bin_centres_pct"]), fontsize=7)
    up, dn = d["direction_rms"]
    ax.set_xlabel("OP bin centre [%]")
    ax.set_ylabel("residual RMS")
    ax.set_title(f"by operating point\nRMS opening {up:.3g}, closing {dn:.3g}", fontsize=9)

    ax = fig.add_subplot(gs[2, 2])
    f = np.asarray(d["freq_hz"])
    if f.size:
        ax.semilogy(1.0 / f, np.asarray(d["residual_psd"]) + 1e-300, lw=0.8)
        ax.set_xscale("log")
        plc = d.get("limit_cycle_period_s")
        if plc:
            for h in range(1, 6):
                ax.axvline(plc / h, color="tab:red", ls=":", lw=0.8)
    ax.set_xlabel("period [s]")
    ax.set_ylabel("residual power")
    ax.set_title("residual spectrum\n(red: limit cycle, harmonics)", fontsize=9)
    return fig
