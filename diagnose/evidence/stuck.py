"""Stuck segments and the parallelogram of the PV-OP path (after Kano et al. 2004).

Kano, Maruta, Kugemoto and Shimizu (2004) detect stiction from the sections where the valve
position does not move although the controller output does; the share of such sections is their
stiction index. Without a measured valve position, a self-regulating loop's PV stands in for it
(a flow follows its valve closely). But a PV that stays still while OP moves is also what
a healthy controller achieves while it compensates a slow disturbance. What only a sticky valve
does is the other side of the parallelogram the PV-OP path then traces: after the stuck stretch
the valve slips, and PV moves a lot while OP hardly moves.

The test therefore counts a stuck stretch only when a slip ends it. On the smoothed signals:

* PV is *stuck* where its local rate of change would move it less than a band over a short
  window (twice the smoothing scale); the band is a tenth of PV's own range, or six standard
  deviations of its smoothed noise if larger (a stuck valve's PV still drifts with the loads);
* a *move* is a stretch, not stuck, over which PV changes by at least a fifth of its range (and
  twice the band); the stretches between moves are *plateaus*;
* a move is a *slip* when the plateau before it is stuck (PV's extent over the plateau at most
  half the move) and OP travelled at least twice as far over the plateau as during the move;
* OP's travel counts only over strokes larger than its noise (turning points with a prominence
  of 10 % of OP's range, or five noise standard deviations).

    stuck index = OP travel over plateaus ended by a slip / total OP travel

The test judges self-regulating loops only. In an integrating loop PV's rate of change would
stand in for the valve, but after a slip the integral action keeps OP moving while the rate
changes, so the PV-OP path has no parallelogram to read; `horch_integrating` and `he_curve_fit`
judge integrating loops.

Stiction when the index is at least 0.25, the threshold Yamashita (2006) gives for his comparable
share of stuck time (`yamashita_qsa`); Kano et al. give none for a PV stand-in. The median OP travel of those stuck stretches, the horizontal side of the
parallelogram, is reported as ``apparent_S_pct``: the OP change a stuck valve needs before it
moves, in % of span.
"""

from __future__ import annotations

import numpy as np

from .. import kernels
from ..plain import count
from ._gates import process_gate, record_gate
from ._signals import Prepared, noise_sd, smoothed_noise_sd
from .result import NO_STICTION, STICTION, Evidence, cannot_judge

TEST = "kano_stuck"
THRESHOLD = 0.25
STUCK_BAND_SD = 6.0
STUCK_FRACTION = 0.1
SLIP_FRACTION = 0.2
STROKE_FRACTION = 0.1


def _robust_range(x: np.ndarray) -> float:
    lo, hi = np.percentile(x, [2, 98])
    return float(hi - lo)


def _prominent_peaks(x: np.ndarray, prominence: float) -> np.ndarray:
    """Local maxima of ``x`` at least ``prominence`` above their surroundings (as
    ``scipy.signal.find_peaks(x, prominence=prominence)``)."""
    peaks, prom = kernels.peak_prominences(x)
    return peaks[prom >= prominence]


def turning_points(x: np.ndarray, prominence: float) -> np.ndarray:
    """Indices of the alternating peaks and troughs of ``x`` (with the two ends)."""
    pk = _prominent_peaks(x, prominence)
    tr = _prominent_peaks(-x, prominence)
    idx = np.concatenate([pk, tr])
    kind = np.concatenate([np.ones(pk.shape[0]), -np.ones(tr.shape[0])])
    order = np.argsort(idx)
    idx, kind = idx[order], kind[order]
    keep: list[int] = []
    kinds: list[float] = []
    for i, k in zip(idx, kind):    # one entry per extremum, not per sample
        if kinds and kinds[-1] == k:
            if k * x[i] > k * x[keep[-1]]:
                keep[-1] = int(i)
            continue
        keep.append(int(i))
        kinds.append(k)
    return np.unique(np.concatenate([[0], np.asarray(keep, dtype=np.int64), [x.shape[0] - 1]]))


def _runs(flag: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run-length encoding: starts, ends (exclusive) and values of the runs of a bool array."""
    change = np.flatnonzero(flag[1:] != flag[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [flag.shape[0]]])
    return starts, ends, flag[starts]


def stuck_index(op_s: np.ndarray, m_raw: np.ndarray, m_s: np.ndarray, op_raw: np.ndarray,
                fc: float, scale: float) -> dict[str, float] | None:
    """The parallelogram-confirmed stuck index and its parts; None when OP does not move."""
    n = op_s.shape[0]
    r_op, r_m = _robust_range(op_s), _robust_range(m_s)
    h = max(STROKE_FRACTION * r_op, 5.0 * noise_sd(op_raw))
    tp = turning_points(op_s, h)
    total = float(np.sum(np.abs(np.diff(op_s[tp]))))
    if not total > h or r_m <= 0:
        return None
    sd_s, _ = smoothed_noise_sd(m_raw, m_s, fc)
    band = max(STUCK_BAND_SD * sd_s, STUCK_FRACTION * r_m)
    W = 2.0 * max(scale, 1.0)
    # stuck where the stand-in's local rate of change would move it less than the band over W
    starts, ends, val = _runs(np.abs(np.gradient(m_s)) * W <= band)
    # moves of the valve stand-in: its net change over each moving run
    m_move = np.abs(m_s[ends - 1] - m_s[np.maximum(starts - 1, 0)])
    big = ~val & (m_move >= max(SLIP_FRACTION * r_m, 2.0 * band))
    bs, be, bm = starts[big], ends[big], m_move[big]
    # the record cut into plateaus (everything between big moves) and big moves, alternating
    cuts = np.unique(np.concatenate([[0], bs, be]))
    cuts = cuts[cuts < n]
    op_ext = np.maximum.reduceat(op_s, cuts) - np.minimum.reduceat(op_s, cuts)
    m_ext = np.maximum.reduceat(m_s, cuts) - np.minimum.reduceat(m_s, cuts)
    is_move = np.isin(cuts, bs)
    move_of = {int(c): float(v) for c, v in zip(bs, bm)}
    k = np.flatnonzero(is_move[1:] & ~is_move[:-1]) + 1     # a big move right after a plateau
    jump = np.array([move_of[int(c)] for c in cuts[k]])     # one entry per slip candidate
    plateau_op, plateau_m, move_op = op_ext[k - 1], m_ext[k - 1], op_ext[k]
    slip = (plateau_m <= 0.5 * jump) & (plateau_op >= 2.0 * move_op) & (plateau_op >= h)
    stuck_len = plateau_op[slip]
    stuck_op = np.maximum.reduceat(op_s, starts) - np.minimum.reduceat(op_s, starts)
    raw_stuck = float(np.sum(stuck_op[val & (stuck_op >= h)]))
    return {"index": min(float(stuck_len.sum()) / total, 1.0), "slips": float(slip.sum()),
            "apparent_S_pct": float(np.median(stuck_len)) if stuck_len.shape[0] else 0.0,
            "kano_raw_index": min(raw_stuck / total, 1.0), "op_travel_pct": total,
            "strokes": float(tp.shape[0] - 1), "stuck_band": band}


def kano_stuck(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Stuck stretches ended by slips, from the PV-OP path (after Kano et al. 2004).

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,)
        Process variable, the valve position's stand-in.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint (used only for the smoothing scale).
    integrating : bool or None
        Process type; the test judges only self-regulating loops (False).
    """
    return _kano_stuck(Prepared(op, pv, ts_s, sp), integrating)


def _kano_stuck(p: Prepared, integrating: bool | None) -> Evidence:
    gate = (record_gate(TEST, p, threshold=THRESHOLD)
            or process_gate(TEST, integrating, wants=False, threshold=THRESHOLD,
                            other="horch_integrating"))
    if gate is not None:
        return gate
    m_raw, m_s = p.pv, p.pv_s
    res = stuck_index(p.op_s, m_raw, m_s, p.op, p.smooth_fc, p.scale)
    if res is None:
        return cannot_judge(TEST, "op_still", "OP does not move beyond its own noise, so no stuck stretch can "
                            "show.", THRESHOLD)
    idx = res.pop("index")
    what = "PV"
    if idx >= THRESHOLD:
        return Evidence(TEST, idx, THRESHOLD, STICTION,
                        f"{what} stays still while OP travels and then jumps ({count(round(res['slips']), 'slip')}; stuck "
                        f"index {idx:.2f} >= {THRESHOLD}), as a sticky valve does; OP moved about "
                        f"{p.op_amount(res['apparent_S_pct'])} before {'the' if round(res['slips']) == 1 else 'each'} "
                        "slip.", extras=res)
    return Evidence(TEST, idx, THRESHOLD, NO_STICTION,
                    f"{what} follows OP without stuck-then-jump stretches (stuck index {idx:.2f} < {THRESHOLD}).",
                    extras=res)
