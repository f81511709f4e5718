"""Choudhury, Shah and Thornhill's higher-order-statistics test, with the apparent stiction.

A linear loop driven by Gaussian noise produces Gaussian signals, whose bicoherence (normalised
bispectrum) is zero at every pair of frequencies. A valve nonlinearity couples the phases of the
oscillation's harmonics, and the squared bicoherence ``bic2(f1, f2)`` becomes large at the coupled
pairs (Choudhury, Shah and Thornhill 2004). From the squared bicoherence of the control error over
the principal domain (K segments):

    bic2_crit = chi2_{0.05}(2) / (2 K)                              (zero bicoherence, 5 % level)
    NGI = mean(bic2) - bic2_crit                                    non-Gaussianity index
    NLI = | max(bic2) - (mean_robust(bic2) + 2 std_robust(bic2)) |  non-linearity index

(robust: the 10 % largest and 10 % smallest values left out). NGI > 0.001: the signal is non-
Gaussian; NLI > 0.01 as well: the loop is nonlinear, and the valve is the first suspect
(Choudhury et al. 2004; thresholds as published). Either index at or below its threshold: the
oscillation has a linear cause, no stiction.

When the loop is nonlinear the PV-OP plot of the signals band-passed around the coupled
frequencies (the frequency-domain Wiener filter of Choudhury, Shah and Thornhill 2008: pass
``min(f1, f2) - 0.05`` to ``max(f1, f2) + 0.05`` cycles per sample around the bicoherence peak)
is fitted with an ellipse; its chord along the OP axis through the centre,

    apparent stiction = 2 m n / sqrt(m^2 sin^2 a + n^2 cos^2 a)

(m, n the semi-axes, a the angle of the major axis to the OP axis) is the apparent stiction in %
of the OP span (Choudhury, Shah, Thornhill and Shook 2006).

Records are decimated so that one oscillation period spans about a quarter of a segment (128
samples, or 64 for short records); the test needs at least 8 segments.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ._gates import record_gate
from ._signals import MIN_PERIOD, Prepared, detrend, lowpass
from .result import NO_STICTION, STICTION, UNDETERMINED, Evidence, cannot_judge

TEST = "choudhury_bicoherence"
NGI_THRESHOLD = 0.001
NLI_THRESHOLD = 0.01
ALPHA = 0.05
MIN_SEGMENTS = 8
BAND_MARGIN = 0.05      # cycles per sample either side of the bicoherence peak (Wiener filter)


@lru_cache(maxsize=4)
def _domain(M: int) -> tuple[np.ndarray, np.ndarray]:
    """Frequency-bin pairs (i, j) of the principal domain: 1 <= j <= i, i + j <= M/2."""
    i, j = np.meshgrid(np.arange(1, M // 2 + 1), np.arange(1, M // 2 + 1), indexing="ij")
    keep = (j <= i) & (i + j <= M // 2)
    return i[keep], j[keep]


def squared_bicoherence(x: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """``(bic2, i, j, K)``: squared bicoherence on the principal domain, from K Hann-windowed
    segments of M samples with half overlap."""
    step = M // 2
    K = (x.shape[0] - M) // step + 1
    idx = np.arange(K)[:, None] * step + np.arange(M)[None, :]
    seg = x[idx]
    seg = seg - seg.mean(axis=1, keepdims=True)
    X = np.fft.rfft(seg * np.hanning(M)[None, :], axis=1)
    i, j = _domain(M)
    x1x2 = X[:, i] * X[:, j]
    x12 = X[:, i + j]
    B = np.mean(x1x2 * np.conj(x12), axis=0)
    den = np.mean(np.abs(x1x2) ** 2, axis=0) * np.mean(np.abs(x12) ** 2, axis=0)
    tiny = 1e-12 * float(den.max()) if den.shape[0] and den.max() > 0 else 1e-300
    return np.abs(B) ** 2 / (den + tiny), i, j, K


def indices(bic2: np.ndarray, K: int) -> tuple[float, float, float]:
    """``(NGI, NLI, bic2_crit)`` of Choudhury et al. (2004)."""
    # chi-square with 2 degrees of freedom has the closed-form quantile -2 ln(alpha) (and
    # scipy.stats costs a noticeable share of the command's start-up)
    crit = -2.0 * math.log(ALPHA) / (2.0 * K)
    ngi = float(np.mean(bic2)) - crit
    lo, hi = np.quantile(bic2, [0.1, 0.9])
    core = bic2[(bic2 >= lo) & (bic2 <= hi)]
    nli = abs(float(bic2.max()) - (float(core.mean()) + 2.0 * float(core.std())))
    return ngi, nli, crit


def fft_bandpass(x: np.ndarray, f_lo: float, f_hi: float) -> np.ndarray:
    """Brick-wall band-pass in the frequency domain (Choudhury's Wiener filter), edges in cycles/sample."""
    X = np.fft.rfft(x)
    f = np.fft.rfftfreq(x.shape[0])
    X[(f < f_lo) | (f > f_hi)] = 0.0
    return np.fft.irfft(X, x.shape[0])


def fit_ellipse(x: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """Conic coefficients (A, B, C, D, E, F) of the least-squares ellipse through the points
    (Fitzgibbon, Pilu and Fisher's direct fit, in Halir and Flusser's stable form); None when the
    points admit no ellipse."""
    D1 = np.column_stack([x * x, x * y, y * y])
    D2 = np.column_stack([x, y, np.ones_like(x)])
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        return None
    Mq = S1 + S2 @ T
    Mq = np.array([Mq[2] / 2.0, -Mq[1], Mq[0] / 2.0])
    try:
        w, v = np.linalg.eig(Mq)
    except np.linalg.LinAlgError:
        return None
    v = np.real(v)
    cond = 4.0 * v[0] * v[2] - v[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.shape[0] == 0:
        return None
    a1 = v[:, ok[0]]
    return np.concatenate([a1, T @ a1])


def apparent_stiction(op_f: np.ndarray, pv_f: np.ndarray) -> tuple[float, float] | None:
    """``(chord along OP through the centre, OP extent of the ellipse)``, in OP units, or None."""
    sx, sy = float(np.std(op_f)), float(np.std(pv_f))
    if not (sx > 0 and sy > 0):
        return None
    x, y = (op_f - op_f.mean()) / sx, (pv_f - pv_f.mean()) / sy
    c = fit_ellipse(x, y)
    if c is None:
        return None
    A, B, C, D, E, F = c
    det = 4.0 * A * C - B * B
    if not det > 0:
        return None
    xc, yc = np.linalg.solve([[2 * A, B], [B, 2 * C]], [-D, -E])
    Fc = A * xc * xc + B * xc * yc + C * yc * yc + D * xc + E * yc + F
    chord2, extent2 = -Fc / A, -Fc * 4.0 * C / det
    if not (chord2 > 0 and extent2 > 0):
        return None
    return 2.0 * np.sqrt(chord2) * sx, 2.0 * np.sqrt(extent2) * sx


def _plan(n: int, period: float | None) -> tuple[int, int] | None:
    """Segment length and decimation factor: one period about a quarter segment, >= 8 segments."""
    for M in (128, 64):
        q = 1 if period is None else max(1, int(period // (M / 4)))
        if (n // q - M) // (M // 2) + 1 >= MIN_SEGMENTS:
            return M, q
    return None


def choudhury_bicoherence(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None) -> Evidence:
    """Choudhury et al.'s NGI/NLI test of the control error, with the apparent stiction from the
    filtered PV-OP ellipse.

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,)
        Process variable.
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; the control error SP - PV is analysed (just -PV when there is none).
    integrating : bool or None
        Not used: the test is the same for either process type.
    """
    return _choudhury_bicoherence(Prepared(op, pv, ts_s, sp))


def _choudhury_bicoherence(p: Prepared) -> Evidence:
    gate = record_gate(TEST, p, threshold=NLI_THRESHOLD)
    if gate is not None:
        return gate
    o = p.osc("err")
    period = o.period if o.period is not None and o.period >= MIN_PERIOD else None
    plan = _plan(p.n, period)
    if plan is None:
        return cannot_judge(TEST, "too_short", f"The record is too short for the bicoherence: fewer than "
                            f"{MIN_SEGMENTS} segments of 64 samples"
                            + (" after decimating to the oscillation." if period else "."), NLI_THRESHOLD)
    M, q = plan
    if q > 1:
        cut = 0.4 / q
        e = lowpass(p.err_d, cut, order=4)[::q]
        u = lowpass(p.op_d, cut, order=4)[::q]
        y = lowpass(p.pv_d, cut, order=4)[::q]
    else:
        e, u, y = p.err_d, p.op_d, p.pv_d
    e = detrend(e)
    bic2, bi, bj, K = squared_bicoherence(e, M)
    ngi, nli, crit = indices(bic2, K)
    k = int(np.argmax(bic2))
    f1, f2 = bi[k] / M, bj[k] / M
    ex = {"NGI": ngi, "NLI": nli, "NGI_threshold": NGI_THRESHOLD, "bic2_crit": crit,
          "bic2_max": float(bic2[k]), "f1_hz": f1 / (q * p.ts_s), "f2_hz": f2 / (q * p.ts_s),
          "segments": float(K), "segment_samples": float(M), "decimation": float(q)}
    what = "the control error" if p.sp_moves else "PV"
    if ngi <= NGI_THRESHOLD:
        return Evidence(TEST, nli, NLI_THRESHOLD, NO_STICTION,
                        f"{what[0].upper() + what[1:]} is Gaussian by its bicoherence (NGI {ngi:.4f} <= "
                        f"{NGI_THRESHOLD}): no sign of a nonlinearity in the loop.", extras=ex)
    if nli <= NLI_THRESHOLD:
        return Evidence(TEST, nli, NLI_THRESHOLD, NO_STICTION,
                        f"{what[0].upper() + what[1:]} is non-Gaussian but its bicoherence is flat (NLI {nli:.4f} "
                        f"<= {NLI_THRESHOLD}): a linear loop with a non-Gaussian disturbance.", extras=ex)
    lo = max(min(f1, f2) - BAND_MARGIN, 0.0)
    hi = min(max(f1, f2) + BAND_MARGIN, 0.5)
    if period is not None:     # the band must hold the oscillation itself
        lo, hi = min(lo, 0.8 * q / period), max(hi, 1.25 * q / period)
    ell = apparent_stiction(fft_bandpass(detrend(u), lo, hi), fft_bandpass(detrend(y), lo, hi))
    if ell is None:
        return Evidence(TEST, nli, NLI_THRESHOLD, UNDETERMINED,
                        f"The loop is nonlinear (NGI {ngi:.4f}, NLI {nli:.3f}) but the filtered PV-OP plot is no "
                        "ellipse: a nonlinearity other than a sticky valve is as likely.", extras=ex)
    chord, extent = ell
    ex.update(apparent_stiction_pct=chord, ellipse_op_extent_pct=extent)
    return Evidence(TEST, nli, NLI_THRESHOLD, STICTION,
                    f"The loop is nonlinear (NGI {ngi:.4f} > {NGI_THRESHOLD}, NLI {nli:.3f} > {NLI_THRESHOLD}); the "
                    f"filtered PV-OP ellipse gives an apparent stiction of {p.op_amount(chord)}.", extras=ex)
