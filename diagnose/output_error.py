"""The output-error cost of Hammerstein candidates: the compiled scoring kernel and its data.

A candidate is a stiction valve (S, J, starting direction f0) and a linear process structure
(kind, lags, dead time). `_Problem` holds a record prepared once (scaled PV, score weights,
orthonormal slow-load basis, noise prefilter) and scores any number of candidates in one compiled
pass (`_ham_sse`): PV is simulated from OP through the valve and the structure, and the gain, the
bias and the load coefficients, being linear, are solved by least squares inside the pass. The
search over candidates is in `diagnose.fit`.

The kernels run their C twins (`diagnose/native/kernels.c`) when there are any; their registry
keys in `diagnose.native` name this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import DataError
from .native import njit  # numba.njit, deferred; runs the C twin when there is one (diagnose/native)
from .process_model import lag_coefficient
from .stiction_model import _batch_kernel

MIN_SAMPLES = 50

# --------------------------------------------------------------------------------------------------
# compiled scoring kernel
# --------------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _valve_smooth(x, s, j, f0, out):  # pragma: no cover - compiled
    """The stiction model with the slip instant interpolated inside the sample.

    Identical to `diagnose.stiction_model.stiction_batch` except on the sample where a slip
    happens: there the output is the *time average* over the sample of a valve that jumps when the
    linearly interpolated input crosses the threshold (the zero-order-hold input the process sees).
    The output is then continuous in S and J, which turns the cost's needle-shaped minimum
    (slips moving by whole samples) into a smooth valley for the search; the final answer is
    polished with the exact model.
    """
    n = x.shape[0]
    half = (s - j) / 2.0
    f = f0
    xp = min(max(x[0], 0.0), 100.0)
    up = False
    yp = xp
    xss = xp
    stuck = True
    out[0] = yp
    for k in range(1, n):
        xk = min(max(x[k], 0.0), 100.0)
        v = xk - xp
        up_k = v > 0.0
        if not stuck and (v == 0.0 or up_k != up):
            stuck = True
            xss = xp
        if stuck:
            d = xk - xss
            thr = 0.0
            moved = False
            if -f * d > s:
                f = -f
                stuck = False
                thr = xss + f * s
                moved = True
            elif f * d > j:
                stuck = False
                thr = xss + f * j
                moved = True
            if moved:
                ynew = min(max(xk - f * half, 0.0), 100.0)
                frac = (xk - thr) / v if v != 0.0 else 1.0
                frac = min(max(frac, 0.0), 1.0)
                out[k] = yp + frac * (ynew - yp)
                yp = ynew
            else:
                out[k] = yp
        else:
            yp = min(max(xk - f * half, 0.0), 100.0)
            out[k] = yp
        xp = xk
        up = up_k
    return out


@njit(cache=True, nogil=True, inline="always")
def _one_structure(u, u0, A1, a2, D, integ, ts, ahp, w, yw, Qw, out):  # pragma: no cover - compiled
    """Normal-equation sums of one structure: out[:K] = Q'z, out[K] = z'z, out[K+1] = z'y."""
    n = u.shape[0]
    K = Qw.shape[1]
    A2 = max(a2, 0.0)
    B1 = 1.0 - A1
    B2 = 1.0 - A2
    I = ts if integ else 0.0
    N = 0.0 if integ else 1.0
    z1 = 0.0
    z2 = 0.0
    acc = 0.0
    prv = 0.0
    f = 0.0
    for j in range(K + 2):
        out[j] = 0.0
    hp = ahp >= 0.0
    for k in range(n):
        kd = k - D
        ud = (u[kd] - u0) if kd >= 0 else 0.0
        z1 = A1 * z1 + B1 * ud
        z2 = A2 * z2 + B2 * z1
        acc += I * z2
        v = N * z2 + acc
        if hp:
            f = ahp * f + v - prv
            prv = v
            v = f
        wk = w[k]
        if wk != 0.0:
            out[K] += wk * v * v
            out[K + 1] += yw[k] * v
            for j in range(K):
                out[j] += Qw[k, j] * v


@njit(cache=True, nogil=True)
def _ham_sse(x, S, J, F, a1, a2, d, integ, ts, ahp, w, yw, Qw, Qty, yyp, sse, gain, smooth, gfix):  # pragma: no cover
    """Output-error SSE of every (valve candidate i, process structure p).

    For each candidate the valve output is computed once; four process structures at a time then
    filter it (lags, dead time, integrator, noise prefilter) and accumulate the weighted normal
    equations against the orthonormal load basis ``Qw`` and the data ``yw``; the residual SSE after
    projecting out the basis and fitting the gain follows in closed form. Four structures per pass
    keep four independent recursions in flight (about twice as fast as one).
    """
    m = S.shape[0]; P = a1.shape[0]; n = x.shape[0]; K = Qw.shape[1]
    mv = np.empty((1, n))
    szq = np.zeros((4, K))
    szq1 = np.zeros(K + 2)
    for i in range(m):
        if smooth:
            _valve_smooth(x, S[i], J[i], F[i], mv[0])
        else:
            _batch_kernel(x, S[i:i + 1], J[i:i + 1], F[i:i + 1], mv)
        u = mv[0]
        u0 = u[0]
        p_single = P - (P % 4) if P % 4 != 0 else P
        for p in range(p_single, P):
            # leftover structures one at a time
            _one_structure(u, u0, a1[p], a2[p], d[p], integ[p], ts, ahp, w, yw, Qw, szq1)
            szz = szq1[K]
            szy = szq1[K + 1]
            zzp = szz
            zyp = szy
            for j in range(K):
                zzp -= szq1[j] * szq1[j]
                zyp -= szq1[j] * Qty[j]
            if gfix == gfix:
                sse[i, p] = yyp - 2.0 * gfix * zyp + gfix * gfix * max(zzp, 0.0)
                gain[i, p] = gfix
            elif zzp > 1e-10 * (szz + 1e-300) and zzp > 1e-300:
                sse[i, p] = yyp - zyp * zyp / zzp
                gain[i, p] = zyp / zzp
            else:
                sse[i, p] = yyp
                gain[i, p] = 0.0
        for p0 in range(0, p_single, 4):
            # four structures at once
            pa = p0; pb = min(p0 + 1, P - 1); pc = min(p0 + 2, P - 1); pd = min(p0 + 3, P - 1)
            A1a = a1[pa]; A1b = a1[pb]; A1c = a1[pc]; A1d = a1[pd]
            B1a = 1.0 - A1a; B1b = 1.0 - A1b; B1c = 1.0 - A1c; B1d = 1.0 - A1d
            A2a = max(a2[pa], 0.0); A2b = max(a2[pb], 0.0); A2c = max(a2[pc], 0.0); A2d = max(a2[pd], 0.0)
            B2a = 1.0 - A2a; B2b = 1.0 - A2b; B2c = 1.0 - A2c; B2d = 1.0 - A2d
            Ia = ts if integ[pa] else 0.0; Ib = ts if integ[pb] else 0.0
            Ic = ts if integ[pc] else 0.0; Id = ts if integ[pd] else 0.0
            Na = 0.0 if integ[pa] else 1.0; Nb = 0.0 if integ[pb] else 1.0
            Nc = 0.0 if integ[pc] else 1.0; Nd = 0.0 if integ[pd] else 1.0
            Da = d[pa]; Db = d[pb]; Dc = d[pc]; Dd = d[pd]
            za1 = zb1 = zc1 = zd1 = 0.0
            za2 = zb2 = zc2 = zd2 = 0.0
            aca = acb = acc_ = acd = 0.0
            pra = prb = prc = prd = 0.0
            fa = fb = fc = fd = 0.0
            sza = szb = szc = szd = 0.0
            sya = syb = syc = syd = 0.0
            szq[:, :] = 0.0
            hp = ahp >= 0.0
            for k in range(n):
                ka = k - Da; kb = k - Db; kc = k - Dc; kd = k - Dd
                ua = (u[ka] - u0) if ka >= 0 else 0.0
                ub = (u[kb] - u0) if kb >= 0 else 0.0
                uc = (u[kc] - u0) if kc >= 0 else 0.0
                ud = (u[kd] - u0) if kd >= 0 else 0.0
                za1 = A1a * za1 + B1a * ua; zb1 = A1b * zb1 + B1b * ub
                zc1 = A1c * zc1 + B1c * uc; zd1 = A1d * zd1 + B1d * ud
                za2 = A2a * za2 + B2a * za1; zb2 = A2b * zb2 + B2b * zb1
                zc2 = A2c * zc2 + B2c * zc1; zd2 = A2d * zd2 + B2d * zd1
                aca += Ia * za2; acb += Ib * zb2; acc_ += Ic * zc2; acd += Id * zd2
                va = Na * za2 + aca; vb = Nb * zb2 + acb; vc = Nc * zc2 + acc_; vd = Nd * zd2 + acd
                if hp:
                    fa = ahp * fa + va - pra; pra = va; va = fa
                    fb = ahp * fb + vb - prb; prb = vb; vb = fb
                    fc = ahp * fc + vc - prc; prc = vc; vc = fc
                    fd = ahp * fd + vd - prd; prd = vd; vd = fd
                wk = w[k]
                if wk != 0.0:
                    yk = yw[k]
                    sza += wk * va * va; szb += wk * vb * vb; szc += wk * vc * vc; szd += wk * vd * vd
                    sya += yk * va; syb += yk * vb; syc += yk * vc; syd += yk * vd
                    for j in range(K):
                        q = Qw[k, j]
                        szq[0, j] += q * va; szq[1, j] += q * vb; szq[2, j] += q * vc; szq[3, j] += q * vd
            for g in range(4):
                p = p0 + g
                if p >= P:
                    break
                szz = (sza, szb, szc, szd)[g]
                szy = (sya, syb, syc, syd)[g]
                zzp = szz
                zyp = szy
                for j in range(K):
                    zzp -= szq[g, j] * szq[g, j]
                    zyp -= szq[g, j] * Qty[j]
                if gfix == gfix:
                    sse[i, p] = yyp - 2.0 * gfix * zyp + gfix * gfix * max(zzp, 0.0)
                    gain[i, p] = gfix
                elif zzp > 1e-10 * (szz + 1e-300) and zzp > 1e-300:
                    sse[i, p] = yyp - zyp * zyp / zzp
                    gain[i, p] = zyp / zzp
                else:
                    sse[i, p] = yyp
                    gain[i, p] = 0.0
    return sse


def _legendre_basis(n: int, order: int) -> np.ndarray:
    t = np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(n)
    cols = [np.ones(n)]
    if order >= 1:
        cols.append(t)
    p_prev, p = np.ones(n), t
    for k in range(2, order + 1):
        p_prev, p = p, ((2 * k - 1) * t * p - (k - 1) * p_prev) / k
        cols.append(p)
    return np.stack(cols, axis=1)


# --------------------------------------------------------------------------------------------------
# the fitting problem
# --------------------------------------------------------------------------------------------------

@dataclass
class _Configs:
    a1: np.ndarray
    a2: np.ndarray
    d: np.ndarray
    integ: np.ndarray
    kind: list
    tau: np.ndarray
    tau2: np.ndarray

    def take(self, idx) -> "_Configs":
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        return _Configs(self.a1[idx], self.a2[idx], self.d[idx], self.integ[idx],
                        [self.kind[i] for i in idx], self.tau[idx], self.tau2[idx])

    def __len__(self) -> int:
        return int(self.a1.shape[0])


def _make_configs(entries, ts_s: float, tau_max_s: float = math.inf) -> _Configs:
    """entries: iterable of (kind, tau_s, tau2_s, delay_samples); lags above ``tau_max_s`` are
    clipped to it (the local refinements scale lags freely)."""
    kinds, a1, a2, d, integ, tau, tau2 = [], [], [], [], [], [], []
    for kind, t1, t2, dd in entries:
        t1, t2 = min(t1, tau_max_s), min(t2, tau_max_s)
        kinds.append(kind)
        a1.append(lag_coefficient(t1, ts_s))
        a2.append(lag_coefficient(t2, ts_s) if kind == "soptd" else -1.0)
        d.append(int(dd))
        integ.append(kind == "integrating")
        tau.append(t1)
        tau2.append(t2 if kind == "soptd" else 0.0)
    return _Configs(np.asarray(a1, float), np.asarray(a2, float), np.asarray(d, np.int64),
                    np.asarray(integ, np.bool_), kinds, np.asarray(tau, float), np.asarray(tau2, float))


@njit(cache=True, nogil=True)
def _hp_filter_2d(v, a):  # pragma: no cover - compiled
    n, m = v.shape
    out = np.empty((n, m))
    for j in range(m):
        acc = 0.0
        prev = v[0, j]
        for k in range(n):
            acc = a * acc + v[k, j] - prev
            prev = v[k, j]
            out[k, j] = acc
    return out


def _hp_filter(v: np.ndarray, a: float) -> np.ndarray:
    """``(1 - q^-1) / (1 - a q^-1)`` along axis 0, starting at rest at the first sample."""
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 1:
        return _hp_filter_2d(np.ascontiguousarray(arr[:, None]), float(a))[:, 0]
    if arr.shape[1] == 0:
        return np.zeros_like(arr)
    return _hp_filter_2d(np.ascontiguousarray(arr), float(a))


def _score_design(z: np.ndarray, n: int, load_order: int, ahp: float) -> np.ndarray:
    """Columns [z, load basis] as the search scores them (prefiltered when ``ahp >= 0``)."""
    B = _legendre_basis(n, load_order)
    if ahp >= 0:
        return np.column_stack([_hp_filter(z, ahp), _hp_filter(B[:, 1:], ahp) if load_order >= 1
                                else np.zeros((n, 0))])
    return np.column_stack([z, B])


class _Problem:
    """Data prepared once: scaled PV, score weights, orthonormal load basis, noise prefilter."""

    def __init__(self, x: np.ndarray, y: np.ndarray, ts_s: float, w: np.ndarray, load_order: int,
                 hp_tau_s: float | None = None, gain_fixed: float | None = None,
                 gain_sign: float | None = None):
        self.x = np.ascontiguousarray(x, dtype=np.float64)
        self.ts_s = float(ts_s)
        self.n = x.shape[0]
        self.w = np.ascontiguousarray(w, dtype=np.float64)
        self.n_scored = int(np.count_nonzero(self.w))
        ws = self.w > 0
        self.y_mean = float(np.mean(y[ws]))
        self.y_std = float(np.std(y[ws])) or 1.0
        yn = (y - self.y_mean) / self.y_std
        self.yraw = np.asarray(y, dtype=float)
        self.load_order = load_order
        B = _legendre_basis(self.n, load_order)
        self.hp_tau_s = float(hp_tau_s) if hp_tau_s is not None and hp_tau_s > 0 else None
        if hp_tau_s is not None and hp_tau_s > 0:
            self.ahp = math.exp(-ts_s / hp_tau_s)
            yn = _hp_filter(yn, self.ahp)
            B = _hp_filter(B[:, 1:], self.ahp) if load_order >= 1 else np.zeros((self.n, 0))
        else:
            self.ahp = -1.0
        self.y = np.ascontiguousarray(yn)
        self.yw = self.w * self.y
        if B.shape[1] > 0:
            # Orthonormalise the basis on the scored samples: Q = B R^-1 with Q_s^T Q_s = I.
            _, R = np.linalg.qr(B[ws])
            self.Q = np.linalg.solve(R.T, B.T).T
        else:
            self.Q = np.zeros((self.n, 0))
        self.Qw = np.ascontiguousarray(self.Q * self.w[:, None])
        self.Qty = self.Qw.T @ self.y
        self.sst = float(np.sum(self.yw * self.y))
        self.yyp = float(self.sst - self.Qty @ self.Qty)
        self.evals = 0
        self.smooth = False     # True scores `_valve_smooth` (slip instant interpolated)
        self.gain_fixed = gain_fixed
        self.gain_sign = float(np.sign(gain_sign)) if gain_sign else 0.0

    def sse(self, S, J, F, cfg: _Configs) -> tuple[np.ndarray, np.ndarray]:
        S = np.ascontiguousarray(S, dtype=np.float64)
        J = np.ascontiguousarray(J, dtype=np.float64)
        F = np.ascontiguousarray(F, dtype=np.float64)
        m, P = S.shape[0], len(cfg)
        out = np.empty((m, P))
        gain = np.empty((m, P))
        _ham_sse(self.x, S, J, F, cfg.a1, cfg.a2, cfg.d, cfg.integ, self.ts_s, self.ahp, self.w, self.yw,
                 self.Qw, self.Qty, self.yyp, out, gain, self.smooth,
                 self.gain_fixed / self.y_std if self.gain_fixed is not None else np.nan)
        self.evals += m * P * self.n
        if self.gain_sign:
            # a process gain against the controller's action is the controller path (PV explained
            # through OP = f(PV)), not the plant: score it no better than no process at all
            np.copyto(out, np.maximum(out, self.yyp), where=gain * self.gain_sign < 0)
        return np.maximum(out, 0.0), gain


def _burn_in(x: np.ndarray, burn_frac: float) -> int:
    """Samples left out of the score at the start: the valve's initial state is unknown.

    At least ``burn_frac`` of the record, and until OP has travelled over 60 % of its robust range
    and back by half of that (a candidate valve started at rest has then moved both ways and is in
    step with the plant's); never more than a quarter of the record.
    """
    n = x.shape[0]
    lo, hi = np.percentile(x, [0.5, 99.5])
    need = 0.6 * (hi - lo)
    run_max = np.maximum.accumulate(x)
    run_min = np.minimum.accumulate(x)
    k = np.flatnonzero(run_max - run_min >= need)
    burn = int(burn_frac * n)
    if k.size:
        k1 = int(k[0])
        # ... and back: the first reversal by half of that after k1
        up = x[k1] >= x[0] + 0.5 * (run_max[k1] - run_min[k1]) - 1e-12
        tail = x[k1:]
        ext = np.maximum.accumulate(tail) if up else np.minimum.accumulate(tail)
        back = np.flatnonzero(np.abs(ext - tail) >= 0.5 * need)
        k2 = k1 + int(back[0]) if back.size else n
        burn = max(burn, k2)
    else:
        burn = n
    return int(min(max(burn, 3), n // 4))


def _score_weights(n: int, train, burn: int) -> np.ndarray:
    w = np.zeros(n)
    if train is None:
        w[:] = 1.0
    else:
        t = np.asarray(train) if not isinstance(train, slice) else None
        if isinstance(train, slice):
            w[train] = 1.0
        elif t.dtype == bool:
            if t.shape[0] != n:
                raise DataError(f"train mask has {t.shape[0]} samples, the record {n}")
            w[t] = 1.0
        else:
            w[t.astype(np.int64)] = 1.0
    w[:burn] = 0.0
    if np.count_nonzero(w) < MIN_SAMPLES // 2:
        raise DataError(f"only {int(np.count_nonzero(w))} samples left to score the fit; "
                        f"give a longer record or a larger training set")
    return w
