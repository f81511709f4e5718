"""What the fit scores: the output error of valve + process candidates, as a public immutable object.

The model: controller output OP --[two-parameter stiction valve (S, J, f0)]--> stem position
--[low-order linear process (`diagnose.process_model.ProcessModel`: FOPTD / SOPTD / integrating,
dead time)]--> PV, plus a constant and a slow load (Legendre polynomial in time). PV is simulated
from OP alone, never from measured PV (**output error**): in closed loop a model fed with
measured PV can explain PV through the controller instead of the valve (docs/fitting.md).

`Objective` holds a record prepared once and scores any number of candidates in one compiled pass
(`diagnose.kernels.score`): for each valve candidate and each process structure it simulates the
stem and the unit-gain process response, and solves the gain, the bias and the load coefficients,
being linear, by least squares inside the pass (separable least squares). What is scored:

* the samples of ``weights`` (zero during the burn-in, `burn_in`, and outside a training mask);
* PV and the simulated response both passed through the noise prefilter ``1/H`` of an
  integrated-noise model ``H = (1 - a q^-1) / (1 - q^-1)``, ``a = exp(-ts / hp_tau_s)`` (prediction
  error with a fixed noise model; ``hp_tau_s=None``: plain output error);
* a slow load of Legendre order ``load_order`` (0: a constant only), fitted per candidate;
* the process gain: free, fixed (``gain_fixed``), or held to the controller's sign (``gain_sign``:
  a candidate whose gain has the other sign scores as no process at all, since in closed loop it is
  the controller path ``PV = -OP / Kc``, not the plant).

Search strategies (`diagnose.search`) take an `Objective` and never change it: a different start
state of the valve or noise model is a new objective (`Objective.with_start`, `Objective.with_noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Iterable, Sequence

import numpy as np

from . import kernels
from .errors import DataError
from .process_model import KINDS, ProcessModel, lag_coefficient

#: Fewest samples a record may have.
MIN_SAMPLES = 50

#: A process structure: (kind, tau_s, tau2_s, dead time in samples); gain and bias are fitted.
StructureKey = tuple


# --------------------------------------------------------------------------------------------------
# process structures, vectorised for the kernel
# --------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ProcessGrid:
    """Process structures in the form the scoring kernel takes (one column per structure).

    Build with `ProcessGrid.of`; ``keys[i]`` is ``(kind, tau_s, tau2_s, delay_samples)``; ``table``
    is (4, P): the lag poles a1 and a2 (-1: first order), the dead time in samples and the
    integrator flag.
    """

    keys: tuple
    ts_s: float
    table: np.ndarray

    @classmethod
    def of(cls, keys: Iterable[StructureKey], ts_s: float, tau_max_s: float = math.inf) -> "ProcessGrid":
        """Structures from ``(kind, tau_s, tau2_s, delay_samples)`` keys; lags above ``tau_max_s``
        are clipped to it (local searches scale lags freely)."""
        out, rows = [], []
        for kind, t1, t2, dd in keys:
            if kind not in KINDS:
                raise DataError(f"unknown process kind {kind!r}; use foptd, soptd or integrating")
            t1 = min(float(t1), tau_max_s)
            t2 = min(float(t2), tau_max_s) if kind == "soptd" else 0.0
            out.append((kind, t1, t2, int(dd)))
            rows.append((lag_coefficient(t1, ts_s), lag_coefficient(t2, ts_s) if kind == "soptd" else -1.0,
                         float(int(dd)), 1.0 if kind == "integrating" else 0.0))
        table = np.ascontiguousarray(np.asarray(rows, dtype=np.float64).reshape(-1, 4).T)
        table.flags.writeable = False
        return cls(tuple(out), float(ts_s), table)

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def d(self) -> np.ndarray:
        """Dead times, samples."""
        return self.table[2].astype(np.int64)

    def take(self, idx) -> "ProcessGrid":
        idx = np.atleast_1d(np.asarray(idx, dtype=np.int64))
        table = np.ascontiguousarray(self.table[:, idx])
        table.flags.writeable = False
        return ProcessGrid(tuple(self.keys[i] for i in idx), self.ts_s, table)

    def model(self, i: int = 0) -> ProcessModel:
        """Structure ``i`` as a unit-gain, zero-bias `ProcessModel`."""
        kind, t1, t2, dd = self.keys[i]
        return ProcessModel(kind=kind, gain=1.0, tau_s=t1, delay_s=dd * self.ts_s, bias=0.0, tau2_s=t2)


@dataclass(frozen=True)
class Candidate:
    """One scored candidate: the valve (S, J in % of span, starting direction f0), the process
    structure key, and the objective's cost (scaled SSE: `Objective.mse` turns it into PV units)."""

    S_pct: float
    J_pct: float
    f0: float
    structure: StructureKey
    sse: float

    def grid(self, ts_s: float, tau_max_s: float = math.inf) -> ProcessGrid:
        return ProcessGrid.of([self.structure], ts_s, tau_max_s)

    def with_valve(self, S_pct: float, J_pct: float, f0: float, sse: float) -> "Candidate":
        return Candidate(float(S_pct), float(J_pct), float(f0), self.structure, float(sse))


# --------------------------------------------------------------------------------------------------
# the data side: burn-in, weights, load basis, noise prefilter
# --------------------------------------------------------------------------------------------------

def legendre_basis(n: int, order: int) -> np.ndarray:
    """Columns 1, P1(t), ..., P_order(t) on t in -1..1 over ``n`` samples (the slow load)."""
    t = np.linspace(-1.0, 1.0, n) if n > 1 else np.zeros(n)
    cols = [np.ones(n)]
    if order >= 1:
        cols.append(t)
    p_prev, p = np.ones(n), t
    for k in range(2, order + 1):
        p_prev, p = p, ((2 * k - 1) * t * p - (k - 1) * p_prev) / k
        cols.append(p)
    return np.stack(cols, axis=1)


def noise_prefilter(v: np.ndarray, a: float) -> np.ndarray:
    """``(1 - q^-1) / (1 - a q^-1)`` along axis 0, starting at rest at the first sample."""
    arr = np.asarray(v, dtype=np.float64)
    if arr.ndim == 2 and arr.shape[1] == 0:
        return np.zeros_like(arr)
    return kernels.hp_filter(arr, float(a))


def score_design(z: np.ndarray, n: int, load_order: int, ahp: float) -> np.ndarray:
    """Columns [z, load basis] as the objective scores them (prefiltered when ``ahp >= 0``; the
    prefilter removes the constant)."""
    B = legendre_basis(n, load_order)
    if ahp >= 0:
        return np.column_stack([noise_prefilter(z, ahp), noise_prefilter(B[:, 1:], ahp) if load_order >= 1
                                else np.zeros((n, 0))])
    return np.column_stack([z, B])


def burn_in(x: np.ndarray, burn_frac: float) -> int:
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


def score_weights(n: int, train, burn: int) -> np.ndarray:
    """1 on the samples the fit may score (``train``: slice, bool mask or indices; None: all), 0 on
    the others and in the first ``burn`` samples."""
    w = np.zeros(n)
    if train is None:
        w[:] = 1.0
    elif isinstance(train, slice):
        w[train] = 1.0
    else:
        t = np.asarray(train)
        if t.dtype == bool:
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


def op_offset(x: np.ndarray) -> float:
    """Shift that brings OP into 0..100 % when it is not (e.g. mean-centred data)."""
    lo, hi = float(np.min(x)), float(np.max(x))
    if lo >= 0.0 and hi <= 100.0:
        return 0.0
    if hi - lo < 100.0:
        return 50.0 - 0.5 * (lo + hi)
    raise DataError(f"OP spans {lo:g}..{hi:g}, more than a valve's 0..100 %; scale it to % of span")


def validate_record(op_pct, pv, ts_s: float, y_name: str = "PV") -> tuple[np.ndarray, np.ndarray]:
    """OP and PV (or the series named ``y_name``) as float arrays, with the errors a user can act on."""
    x = np.asarray(op_pct, dtype=float)
    y = np.asarray(pv, dtype=float)
    if x.ndim != 1 or y.ndim != 1 or x.shape != y.shape:
        raise DataError(f"OP and {y_name} must be 1-D series of equal length, got {x.shape} and {y.shape}")
    if x.shape[0] < MIN_SAMPLES:
        raise DataError(f"record has {x.shape[0]} samples; the fit needs at least {MIN_SAMPLES}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise DataError(f"OP and {y_name} must be finite; fill or split gaps first")
    if not (ts_s > 0 and math.isfinite(ts_s)):
        raise DataError(f"ts_s must be a positive number of seconds, got {ts_s!r}")
    if np.ptp(x) <= 0:
        raise DataError("OP is constant: the controller never moved the valve, nothing to identify")
    if np.ptp(y) <= 0:
        raise DataError(f"{y_name} is constant: nothing to identify")
    return x, y


# --------------------------------------------------------------------------------------------------
# the objective
# --------------------------------------------------------------------------------------------------

def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Objective:
    """The output-error cost of valve + process candidates on one record (immutable).

    Parameters
    ----------
    x : ndarray (n,)
        Valve input: OP in % of span (plus `op_offset`); the valve starts at rest at ``x[0]``.
    y : ndarray (n,)
        PV, engineering units.
    ts_s : float
        Sample period, seconds.
    weights : ndarray (n,)
        1 on the scored samples, 0 elsewhere (`score_weights`).
    load_order : int
        Legendre order of the slow load (0: a constant only).
    hp_tau_s : float or None
        Noise prefilter time constant, seconds (None: plain output error).
    gain_fixed : float or None
        Fix the process gain (PV units per %) instead of fitting it (the valve fit's 1).
    gain_sign : {+1, -1} or None
        Sign the process gain must have (the controller's action).
    start_stem_pct, start_stuck_pct : float or None
        The valve's stem at the first sample, % of span, stuck there after a motion in the
        candidate's direction f0 (the valve fit reads it from the recorded stem position), and the
        input at which it stuck (None: where a valve moving in direction f0 stops,
        ``stem + f0 (S - J) / 2``). None: at rest at ``x[0]``.

    Use `Objective.build` to make one from a record.
    """

    x: np.ndarray
    y: np.ndarray
    ts_s: float
    weights: np.ndarray
    load_order: int = 2
    hp_tau_s: float | None = None
    gain_fixed: float | None = None
    gain_sign: float | None = None
    start_stem_pct: float | None = None
    start_stuck_pct: float | None = None
    # derived once (__post_init__)
    ahp: float = field(init=False)
    y_mean: float = field(init=False)
    y_std: float = field(init=False)
    n_scored: int = field(init=False)
    _yyp: float = field(init=False, repr=False)
    _data: kernels.ScoreData = field(init=False, repr=False)
    _noise_variants: dict = field(init=False, repr=False)

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "x", _frozen(self.x))
        s(self, "y", _frozen(self.y))
        s(self, "weights", _frozen(self.weights))
        hp = float(self.hp_tau_s) if self.hp_tau_s is not None and self.hp_tau_s > 0 else None
        s(self, "hp_tau_s", hp)
        n = self.x.shape[0]
        w = self.weights
        ws = w > 0
        s(self, "n_scored", int(np.count_nonzero(w)))
        s(self, "y_mean", float(np.mean(self.y[ws])))
        s(self, "y_std", float(np.std(self.y[ws])) or 1.0)
        yn = (self.y - self.y_mean) / self.y_std
        B = legendre_basis(n, self.load_order)
        if hp is not None:
            ahp = math.exp(-self.ts_s / hp)
            yn = noise_prefilter(yn, ahp)
            B = noise_prefilter(B[:, 1:], ahp) if self.load_order >= 1 else np.zeros((n, 0))
        else:
            ahp = -1.0
        s(self, "ahp", ahp)
        if B.shape[1] > 0:
            # orthonormalise the basis on the scored samples: Q = B R^-1 with Q_s^T Q_s = I
            _, R = np.linalg.qr(B[ws])
            Q = np.linalg.solve(R.T, B.T).T
        else:
            Q = np.zeros((n, 0))
        yw = w * yn
        Qw = np.ascontiguousarray(Q * w[:, None])
        Qty = Qw.T @ yn
        s(self, "_yyp", float(np.sum(yw * yn) - Qty @ Qty))
        gfix = self.gain_fixed / self.y_std if self.gain_fixed is not None else np.nan
        s(self, "_data", kernels.ScoreData(self.x, w, yw, Qw, Qty, self._yyp, ahp, self.ts_s, gfix))
        # the same data under other noise models, made once (the noise-model choice and every
        # whole-record refinement try them all); shared by the start variants of `with_start`
        s(self, "_noise_variants", {hp: self})

    @classmethod
    def build(cls, op_pct, pv, ts_s: float, *, train=None, burn_frac: float = 0.05, load_order: int = 2,
              hp_tau_s: float | None = None, gain_fixed: float | None = None,
              gain_sign: float | None = None, offset_pct: float | None = None) -> "Objective":
        """The objective of a record: OP shifted into 0..100 % (`op_offset`, unless ``offset_pct``
        is given), the burn-in (`burn_in`) and the training mask in the weights."""
        x, y = validate_record(op_pct, pv, ts_s)
        x = x + (op_offset(x) if offset_pct is None else offset_pct)
        w = score_weights(x.shape[0], train, burn_in(x, burn_frac))
        return cls(x, y, float(ts_s), w, load_order, hp_tau_s, gain_fixed,
                   float(np.sign(gain_sign)) if gain_sign else None)

    # ---- variants ---------------------------------------------------------------------------------

    def with_start(self, x0_pct: float | None) -> "Objective":
        """The same objective with the valve at rest at ``x0_pct`` instead of OP's first sample
        (None: OP's first sample, i.e. ``x[0]`` of ``self``)."""
        if x0_pct is None or float(x0_pct) == float(self.x[0]):
            return self
        x = np.array(self.x)
        x[0] = x0_pct
        new = object.__new__(Objective)
        new.__dict__.update(self.__dict__)
        object.__setattr__(new, "x", _frozen(x))
        d = self._data
        object.__setattr__(new, "_data", kernels.ScoreData(new.x, d.w, d.yw, d.Qw, d.Qty, d.yyp, d.ahp, d.ts_s,
                                                           d.gfix))
        return new

    def with_start_stem(self, stem_pct: float | None, stuck_pct: float | None = None) -> "Objective":
        """The same objective with the valve stuck at stem position ``stem_pct`` at the first sample,
        the input then at ``stuck_pct`` (None: where a moving valve stops); ``stem_pct`` None: at
        rest at ``x[0]``."""
        stem = None if stem_pct is None or math.isnan(stem_pct) else float(stem_pct)
        stuck = None if stem is None or stuck_pct is None or math.isnan(stuck_pct) else float(stuck_pct)
        # the start state is not part of the prepared data (the kernel takes it with each valve):
        # share them rather than prepare them again
        new = object.__new__(Objective)
        new.__dict__.update(self.__dict__)
        object.__setattr__(new, "start_stem_pct", stem)
        object.__setattr__(new, "start_stuck_pct", stuck)
        # `with_noise` variants keep the start they were made from
        object.__setattr__(new, "_noise_variants", {self.hp_tau_s: new})
        return new

    def with_noise(self, hp_tau_s: float | None) -> "Objective":
        """The same data scored with another noise prefilter (the valve's start kept)."""
        key = float(hp_tau_s) if hp_tau_s is not None and hp_tau_s > 0 else None
        if key == self.hp_tau_s:
            return self
        variants = self._noise_variants
        other = variants.get(key)
        if other is None:
            other = replace(self, hp_tau_s=key)
            object.__setattr__(other, "_noise_variants", variants)
            variants[key] = other
        return other.with_start(float(self.x[0]))

    def with_weights(self, weights: np.ndarray) -> "Objective":
        return replace(self, weights=weights)

    def window(self, i0: int, m: int, burn_frac: float = 0.05) -> "Objective":
        """Samples ``i0 .. i0 + m`` as an objective of their own: the valve starts at rest at the
        window's first OP sample, and the window's own burn-in (`burn_in`) is left out of the score
        (as are the samples left out here)."""
        sl = slice(i0, i0 + m)
        w = np.array(self.weights[sl])
        w[: burn_in(self.x[sl], burn_frac)] = 0.0
        return replace(self, x=self.x[sl], y=self.y[sl], weights=w, start_stem_pct=None, start_stuck_pct=None)

    # ---- scoring ----------------------------------------------------------------------------------

    @property
    def n(self) -> int:
        return int(self.x.shape[0])

    def score(self, S_pct: Sequence[float], J_pct: Sequence[float], f0: Sequence[float],
              grid: ProcessGrid) -> tuple[np.ndarray, np.ndarray]:
        """Scaled SSE and gain of every (valve candidate, structure): two (m, P) arrays.

        The SSE is of the prefiltered, standardised PV (`mse` converts it); a gain against
        ``gain_sign`` scores as no process at all.
        """
        S = np.asarray(S_pct, dtype=np.float64)
        valves = np.empty((5, S.shape[0]))
        valves[0] = S
        valves[1] = J_pct
        valves[2] = f0
        valves[3] = np.nan if self.start_stem_pct is None else self.start_stem_pct
        valves[4] = np.nan if self.start_stuck_pct is None else self.start_stuck_pct
        return self.score_table(valves, grid.table)

    def score_table(self, valves: np.ndarray, structs: np.ndarray,
                    paired: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """`score` with the valves as a (5, m) array (S, J, f0, and the start state y0, xs0: the
        stem stuck at y0 after a motion in direction f0, the input then at xs0; NaN: at rest at
        ``x[0]``) and the structures as a `ProcessGrid.table` (4, P): the local searches' fast path
        and the valve fit's start states. ``paired`` (P = m): valve i with structure i only, two
        (m,) arrays."""
        sse, gain = kernels.score(self._data, valves, structs, paired)
        if self.gain_sign:
            # a process gain against the controller's action is the controller path (PV explained
            # through OP = f(PV)), not the plant: score it no better than no process at all
            np.copyto(sse, np.maximum(sse, self._yyp), where=gain * self.gain_sign < 0)
        return np.maximum(sse, 0.0), gain

    def cost(self, cand: Candidate, tau_max_s: float = math.inf) -> float:
        """Scaled SSE of one candidate."""
        sse, _ = self.score([cand.S_pct], [cand.J_pct], [cand.f0], cand.grid(self.ts_s, tau_max_s))
        return float(sse[0, 0])

    def mse(self, sse) -> float | np.ndarray:
        """Scaled SSE -> mean squared (prefiltered) error per scored sample, PV units squared."""
        return np.asarray(sse) * (self.y_std ** 2 / max(1, self.n_scored))

    @property
    def no_process_sse(self) -> float:
        """Scaled SSE of a model without process (load and constant only)."""
        return self._yyp
