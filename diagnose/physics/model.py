"""The augmented Hammerstein model every hypothesis fits, and what is scored.

Model (one *stage* of the loop, input ``x`` and target ``y``)::

    stem  = augmented_valve(x; S_up, J_up, S_dn, J_dn, dS, dJ, f0, tau_lag)   (identity when the
                                                                               input is already MV)
    u     = characteristic(stem; c)                                           (c = 0: linear)
    z     = ProcessModel(kind, tau, tau2, delay).regressor(u)                 (identity on the valve stage)
    y_hat = gain * z + bias [+ slope * t (integrating)] [+ a sin(w t) + b cos(w t)]

A `Structure` holds the physical parameters of one such model; the linear coefficients (gain,
bias, slope, a, b) are solved by least squares on the *training* samples for every candidate
(separable least squares). A `Stage` holds the data and its training mask and is the objective:
`train_sse` scores any number of structures on it in one compiled pass, `predict` simulates one
over the whole record. The searches that fit structures are in `diagnose.physics.search`. Stages:

* ``loop``: OP -> PV, the fitting stage's Hammerstein model (OP/PV records);
* ``valve``: OP -> MV, the valve alone (records with the stem position).
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import math
import operator
from dataclasses import dataclass
from typing import Iterable, Sequence, Union

import numpy as np

from .. import kernels
from ..errors import DataError
from ..process_model import ProcessModel, lag_coefficient
from .valve import augmented_valve, characteristic

IDENTITY = ProcessModel(kind="foptd", gain=1.0, tau_s=0.0, delay_s=0.0, bias=0.0)


@dataclass(frozen=True)
class Structure:
    """Physical parameters of one augmented model (the linear coefficients are refit per use).

    Parameters
    ----------
    S_up_pct, J_up_pct, S_dn_pct, J_dn_pct : float
        Stiction opening / closing, % of span.
    dS_pct_per_s, dJ_pct_per_s : float
        Rate at which S and J change while they drift, % of span per second.
    drift_from_s, drift_for_s : float
        When the drift starts (seconds after the first sample) and how long it lasts (seconds;
        inf: to the end). 0 and inf are a linear drift over the whole record; a drift of one
        sample period is a step of ``dS_pct_per_s * ts`` at ``drift_from_s`` (friction changed by
        a maintenance action, a trip, a temperature change).
    f0 : {+1, -1}
        Starting direction of the valve.
    tau_lag_s : float
        Actuator lag after the friction, seconds.
    tau_pre_s : float
        Actuator lag before the friction, seconds: OP reaches the friction element through a
        first-order lag (a pneumatic actuator's pressure, which the friction then resists).
    char_c : float
        Installed characteristic exponent c = ln R (0: linear).
    process : ProcessModel
        Dynamics of the linear part (gain and bias are refit).
    period_s : float or None
        Period of an additive sinusoidal load.
    y0_pct : float or None
        Stem position at the first sample (the valve's unknown initial state: stuck there after a
        motion in direction ``f0``), % of span; None: stuck at the first OP sample.
    xs0_pct : float or None
        OP at which it stuck (with ``y0_pct``); None: ``y0 + f0 (S - J) / 2``, where a valve moving
        in direction ``f0`` stops.
    """

    S_up_pct: float = 0.0
    J_up_pct: float = 0.0
    S_dn_pct: float = 0.0
    J_dn_pct: float = 0.0
    dS_pct_per_s: float = 0.0
    dJ_pct_per_s: float = 0.0
    drift_from_s: float = 0.0
    drift_for_s: float = math.inf
    f0: int = 1
    tau_lag_s: float = 0.0
    char_c: float = 0.0
    process: ProcessModel = IDENTITY
    period_s: float | None = None
    y0_pct: float | None = None
    xs0_pct: float | None = None
    tau_pre_s: float = 0.0

    @classmethod
    def plain(cls, S_pct: float, J_pct: float, f0: int, process: ProcessModel) -> "Structure":
        return cls(S_up_pct=S_pct, J_up_pct=J_pct, S_dn_pct=S_pct, J_dn_pct=J_pct, f0=int(f0),
                   process=process)

    def friction_at(self, t_s: float) -> tuple[float, float]:
        """Opening S and J ``t_s`` seconds after the first sample (``inf``: after the drift window
        or step), as the valve kernel computes them (`diagnose.kernels.valve_friction`)."""
        su, ju, _, _ = kernels.valve_friction(self.S_up_pct, self.J_up_pct, self.S_dn_pct, self.J_dn_pct,
                                              self.dS_pct_per_s, self.dJ_pct_per_s, self.drift_from_s,
                                              self.drift_for_s, t_s)
        return su, ju

    def plain_part(self) -> "Structure":
        """The plain valve and process of this structure: no lag, characteristic, load, drift or
        drift window (S and J those at the first sample)."""
        return self.replace(tau_lag_s=0.0, tau_pre_s=0.0, char_c=0.0, period_s=None, dS_pct_per_s=0.0, dJ_pct_per_s=0.0,
                            drift_from_s=0.0, drift_for_s=math.inf)

    def replace(self, **kw) -> "Structure":
        # hot path of the searches (hundreds of thousands of candidates): a plain copy of the
        # fields instead of dataclasses.replace (no __post_init__ to run)
        bad = set(kw) - _STRUCT_FIELDS
        if bad:
            raise TypeError(f"Structure has no field(s) {sorted(bad)}")
        new = object.__new__(Structure)
        d = new.__dict__
        d.update(self.__dict__)
        d.update(kw)
        return new


_STRUCT_FIELDS = frozenset(f.name for f in dataclasses.fields(Structure))
_PROCESS_TIMES = frozenset(("tau_s", "tau2_s", "delay_s"))


def with_times(p: ProcessModel, **times: float) -> ProcessModel:
    """``p`` with other time constants or dead time (``tau_s``, ``tau2_s``, ``delay_s``, seconds, >= 0):
    `dataclasses.replace` without re-running the validation of every other field, for the
    searches' grids of dynamics."""
    if not _PROCESS_TIMES.issuperset(times):
        raise TypeError(f"with_times sets {sorted(_PROCESS_TIMES)}, not {sorted(set(times) - _PROCESS_TIMES)}")
    if any(not v >= 0 for v in times.values()):
        raise DataError("process time constants and dead time must be >= 0 seconds")
    new = object.__new__(ProcessModel)
    d = new.__dict__
    d.update(p.__dict__)
    d.update({k: float(v) for k, v in times.items()})
    return new


@dataclass(frozen=True, eq=False)
class Stage:
    """Input, target and split of one stage.

    Parameters
    ----------
    name : {"loop", "valve"}
    x : ndarray (n,)
        Input, % of span (OP).
    y : ndarray (n,)
        Target (PV in engineering units, or MV in %).
    ts_s : float
    train : ndarray of bool (n,)
        Samples the fit may score; the rest is held out.
    gain_sign : {+1, -1, 0}
        Sign the process gain must have (the controller's action, `diagnose.controller`; 0:
        unknown). Passed to the fitting stage, and held by every model here (a least-squares gain
        of the other sign is set to 0), so that no OP -> PV fit can be the controller path
        (``PV = -OP / Kc``).
    """

    name: str
    x: np.ndarray
    y: np.ndarray
    ts_s: float
    train: np.ndarray
    gain_sign: int = 0

    @property
    def n(self) -> int:
        return int(self.x.shape[0])

    @property
    def n_fit(self) -> int:
        """Samples to simulate while searching (through the last training sample)."""
        idx = np.flatnonzero(self.train)
        return int(idx[-1]) + 1 if idx.size else self.n

    @property
    def fixed_dynamics(self) -> bool:
        return self.name == "valve"

    @property
    def heldout(self) -> np.ndarray:
        """Samples after the training part (samples left out at the start are not held out)."""
        return np.arange(self.n) >= self.n_fit


def _design(z: np.ndarray, struct: Structure, ts_s: float, n: int) -> np.ndarray:
    cols = [z, np.ones(n)]
    t = np.arange(n) * ts_s
    if struct.process.kind == "integrating":
        cols.append(t)
    if struct.period_s is not None:
        w = 2.0 * np.pi / struct.period_s
        cols.append(np.sin(w * t))
        cols.append(np.cos(w * t))
    return np.column_stack(cols)


def stems(stage: Stage, structs, n: int | None = None) -> np.ndarray:
    """Simulated stem positions (rows) of many structures (structures, `Candidates` or a `Pool`)
    over the stage's input."""
    n = stage.n if n is None else n
    P = Pool(structs).table()[0]
    out = np.empty((P.shape[0], n))
    for tau in np.unique(P[:, 16]):
        idx = np.flatnonzero(P[:, 16] == tau)
        Q = P[idx]
        out[idx] = augmented_valve(prefiltered(stage.x[:n], float(tau), stage.ts_s), S_up=Q[:, 0], J_up=Q[:, 1],
                                   S_dn=Q[:, 2], J_dn=Q[:, 3], dS_pct_per_s=Q[:, 4], dJ_pct_per_s=Q[:, 5],
                                   f0=Q[:, 6], tau_lag_s=Q[:, 7], y0_pct=Q[:, 12], xs0_pct=Q[:, 13],
                                   drift_from_s=Q[:, 14], drift_for_s=Q[:, 15], ts_s=stage.ts_s)
    return out


def prefiltered(x: np.ndarray, tau_s: float, ts_s: float) -> np.ndarray:
    """The valve's input behind an actuator lag before the friction (`Structure.tau_pre_s`): a
    first-order lag of ``tau_s`` seconds, at rest at the first sample (0: ``x`` itself)."""
    if tau_s <= 0:
        return x
    return kernels.lag_filter(x, lag_coefficient(tau_s, ts_s), -1.0, 0, False, ts_s)


def _linear_fit(stage: Stage, struct: Structure, stem: np.ndarray, n: int):
    u = characteristic(stem, struct.char_c) if struct.char_c else stem
    proc = struct.process
    z = u if (proc.tau_s == 0 and proc.delay_s == 0 and proc.kind != "integrating") \
        else proc.regressor(u, stage.ts_s)
    X = _design(z, struct, stage.ts_s, n)
    tr = stage.train[:n]
    coef, *_ = np.linalg.lstsq(X[tr], stage.y[:n][tr], rcond=None)
    if stage.gain_sign and coef[0] * stage.gain_sign < 0:
        # PV moving against the valve is the controller's path, not the plant's (as in the fitting
        # stage, `Stage.gain_sign`): the valve's column is left out
        rest, *_ = np.linalg.lstsq(X[tr][:, 1:], stage.y[:n][tr], rcond=None)
        coef = np.concatenate([[0.0], rest])
    if not np.all(np.isfinite(coef)):
        coef = np.zeros(X.shape[1])
    return X @ coef, coef


def predict(stage: Stage, struct: Structure, stem: np.ndarray | None = None):
    """Whole-record prediction, with the linear coefficients fitted on the training samples.

    Returns
    -------
    y_hat : ndarray (n,)
    stem : ndarray (n,)
    coef : ndarray
    """
    if stem is None:
        stem = stems(stage, [struct])[0]
    y_hat, coef = _linear_fit(stage, struct, stem, stage.n)
    return y_hat, stem, coef


@functools.lru_cache(maxsize=16)
def _time_column(ts_s: float, n: int, integ: bool) -> np.ndarray:
    """The design's time column of an integrating process (none otherwise), read-only."""
    out = np.ascontiguousarray((np.arange(n) * ts_s)[:, None] if integ else np.zeros((n, 0)))
    out.flags.writeable = False
    return out


_VALVE_FIELDS = operator.attrgetter("S_up_pct", "J_up_pct", "S_dn_pct", "J_dn_pct", "dS_pct_per_s", "dJ_pct_per_s",
                                    "f0", "tau_lag_s", "char_c")


def _row(s: Structure) -> tuple:
    p = s.process
    return _VALVE_FIELDS(s) + (p.tau_s, p.tau2_s if p.kind == "soptd" else -1.0, p.delay_s,
                               np.nan if s.y0_pct is None else s.y0_pct,
                               np.nan if (s.xs0_pct is None or s.y0_pct is None) else s.xs0_pct,
                               s.drift_from_s, s.drift_for_s, s.tau_pre_s)


#: Columns of a parameter row (`_row`).
ROW_WIDTH = 17


#: The fields a `Candidates` column may set, and their column in the kernels' parameter rows
#: (`_row`); ``period_s`` is passed beside the rows.
_ROW_COLUMN = {"S_up_pct": 0, "J_up_pct": 1, "S_dn_pct": 2, "J_dn_pct": 3, "dS_pct_per_s": 4,
               "dJ_pct_per_s": 5, "f0": 6, "tau_lag_s": 7, "char_c": 8, "tau_s": 9, "tau2_s": 10,
               "delay_s": 11, "y0_pct": 12, "xs0_pct": 13, "drift_from_s": 14, "drift_for_s": 15,
               "tau_pre_s": 16, "period_s": None}


class Candidates(Sequence[Structure]):
    """Structures that differ from one ``base`` only in numeric fields, held as columns.

    A search grid holds tens of thousands of candidates; as columns they reach the kernels without
    a Python object each (building one per candidate, under the interpreter lock the other search
    threads wait for, was a large share of an explain), and a `Structure` is made only for a
    candidate read back (``cands[i]``).

    Parameters
    ----------
    base : Structure
        Every field not given as a column, the process kind and whether there is a load.
    **columns : array_like
        Values per candidate, broadcast together and flattened in C order (so
        ``Candidates(b, **dict(zip(names, mesh(a1, a2))))`` lists them as the nested loops
        ``for v1 in a1 for v2 in a2`` would). Any of the valve's fields (``S_up_pct`` ...
        ``xs0_pct``, NaN for None in ``y0_pct`` and ``xs0_pct``; ``f0`` as +-1), ``tau_lag_s``,
        ``char_c``, ``period_s`` (only where ``base`` has a load) and the process's ``tau_s``,
        ``tau2_s`` (second-order processes) and ``delay_s``, seconds.
    """

    __slots__ = ("base", "columns", "_n")

    def __init__(self, base: Structure, **columns):
        bad = set(columns) - set(_ROW_COLUMN)
        if bad:
            raise TypeError(f"Candidates cannot vary {sorted(bad)}")
        if "period_s" in columns and base.period_s is None:
            raise TypeError("period_s varies only around a base that has a load period")
        if "tau2_s" in columns and base.process.kind != "soptd":
            raise TypeError("tau2_s varies only around a second-order (soptd) process")
        arrays = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in columns.values()))
        self.base = base
        self.columns = {k: np.ascontiguousarray(a).reshape(-1) for k, a in zip(columns, arrays)}
        self._n = int(arrays[0].size) if arrays else 1
        for k in _PROCESS_TIMES & set(columns):
            if not np.all(self.columns[k] >= 0):
                raise DataError("process time constants and dead time must be >= 0 seconds")

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(self._n))]
        i = operator.index(i)
        if not -self._n <= i < self._n:
            raise IndexError("candidate index out of range")
        i %= self._n
        kw, times = {}, {}
        for k, col in self.columns.items():
            v = float(col[i])
            if k in _PROCESS_TIMES:
                times[k] = v
            elif k == "f0":
                kw[k] = int(v)
            elif k in ("y0_pct", "xs0_pct"):
                kw[k] = None if math.isnan(v) else v
            else:
                kw[k] = v
        if times:
            kw["process"] = with_times(self.base.process, **times)
        return self.base.replace(**kw)

    def rows(self) -> np.ndarray:
        """The kernels' parameter rows (`_row`), shape (n, `ROW_WIDTH`)."""
        P = np.empty((self._n, ROW_WIDTH))
        P[:] = _row(self.base)
        for k, col in self.columns.items():
            j = _ROW_COLUMN[k]
            if j is not None:
                P[:, j] = col
        # as in `_row`: the OP at which the valve stuck counts only with the position it stuck at
        P[:, 13] = np.where(np.isnan(P[:, 12]), np.nan, P[:, 13])
        return P

    def periods(self) -> np.ndarray | None:
        """The load period of each candidate, seconds (None: no load)."""
        if self.base.period_s is None:
            return None
        col = self.columns.get("period_s")
        return np.full(self._n, float(self.base.period_s)) if col is None else col


def mesh(*axes) -> list[np.ndarray]:
    """Every combination of the axes' values, one flat array per axis, in the order of nested loops
    over them (the first axis outermost): the columns of a grid of `Candidates`."""
    return [g.reshape(-1) for g in np.meshgrid(*(np.asarray(a, dtype=np.float64) for a in axes), indexing="ij")]


class Pool(Sequence[Structure]):
    """Structures and `Candidates` side by side, read and scored as one flat sequence."""

    __slots__ = ("parts", "_ends")

    def __init__(self, items: Iterable[Union[Structure, Candidates]]):
        if isinstance(items, Pool):
            self.parts, self._ends = items.parts, items._ends
            return
        self.parts = [items] if isinstance(items, Candidates) else list(items)
        ends, total = [], 0
        for p in self.parts:
            total += len(p) if isinstance(p, Candidates) else 1
            ends.append(total)
        self._ends = ends

    def __len__(self) -> int:
        return self._ends[-1] if self._ends else 0

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = operator.index(i)
        n = len(self)
        if not -n <= i < n:
            raise IndexError("candidate index out of range")
        i %= n
        k = bisect.bisect_right(self._ends, i)
        part = self.parts[k]
        return part[i - (self._ends[k - 1] if k else 0)] if isinstance(part, Candidates) else part

    def table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Parameter rows (n, `ROW_WIDTH`), whether each candidate has a load, whether its process is
        integrating, and its load's angular frequency (rad/s; NaN without a load)."""
        rows, load, integ, freq = [], [], [], []
        singles: list[Structure] = []

        def flush():
            if singles:
                rows.append(np.array([_row(s) for s in singles], dtype=np.float64).reshape(len(singles), ROW_WIDTH))
                load.append(np.array([s.period_s is not None for s in singles]))
                integ.append(np.array([s.process.kind == "integrating" for s in singles]))
                freq.append(np.array([np.nan if s.period_s is None else 2.0 * np.pi / s.period_s for s in singles],
                                     dtype=np.float64))
                singles.clear()

        for p in self.parts:
            if not isinstance(p, Candidates):
                singles.append(p)
                continue
            flush()
            m = len(p)
            rows.append(p.rows())
            per = p.periods()
            load.append(np.full(m, per is not None))
            integ.append(np.full(m, p.base.process.kind == "integrating"))
            freq.append(np.full(m, np.nan) if per is None else 2.0 * np.pi / per)
        flush()
        if not rows:
            return np.empty((0, ROW_WIDTH)), np.empty(0, bool), np.empty(0, bool), np.empty(0)
        return np.concatenate(rows), np.concatenate(load), np.concatenate(integ), np.concatenate(freq)


def train_sse(stage: Stage, structs: Iterable[Union[Structure, Candidates]]) -> np.ndarray:
    """Training sum of squared errors of each structure (simulated through the training part).

    ``structs``: structures, `Candidates` or a `Pool` of both, scored in their flat order. One
    fused compiled pass per candidate (`diagnose.kernels.fused_sse`, `fused_sse_load` for
    candidates with a load: the valve step, characteristic, lags, least squares): memory does not
    grow with the number of candidates times the record length.
    """
    n = stage.n_fit
    P_all, load_all, integ_all, freq_all = Pool(structs).table()
    x0 = np.ascontiguousarray(stage.x[:n], dtype=np.float64)
    tr = np.ascontiguousarray(stage.train[:n], dtype=np.float64)
    yv = np.ascontiguousarray(stage.y[:n], dtype=np.float64)
    ts = float(stage.ts_s)
    out = np.empty(P_all.shape[0])
    # candidates with a load take its sine and cosine per candidate (a search over periods, or the
    # posterior's draws, would otherwise be one call per period); those with an actuator lag before
    # the friction share one filtered input per lag
    for tau_pre in np.unique(P_all[:, 16]):
        x = np.ascontiguousarray(prefiltered(x0, float(tau_pre), ts))
        for load, integ in ((False, False), (False, True), (True, False), (True, True)):
            idx = np.flatnonzero((load_all == load) & (integ_all == integ) & (P_all[:, 16] == tau_pre))
            if idx.size == 0:
                continue
            P = P_all[idx]
            m = idx.size
            if np.any(P[:, :4] < 0) or not np.all(np.isfinite(P[:, :4])):
                raise DataError("S and J must be finite and >= 0 % of span")
            tl = P[:, 7]
            a_lag = np.where(tl > 0, np.exp(-ts / np.where(tl > 0, tl, 1.0)), 0.0)
            t1 = P[:, 9]
            a1 = np.where(t1 > 0, np.exp(-ts / np.where(t1 > 0, t1, 1.0)), 0.0)
            t2 = P[:, 10]
            a2 = np.where(t2 > 0, np.exp(-ts / np.where(t2 > 0, t2, 1.0)), np.where(t2 < 0, -1.0, 0.0))
            d = np.maximum(np.round(P[:, 11] / ts), 0).astype(np.int64)
            params = np.column_stack([P[:, 0], P[:, 1], P[:, 2], P[:, 3], P[:, 4], P[:, 5], P[:, 14], P[:, 15],
                                      P[:, 6], a_lag, P[:, 12], P[:, 13]])
            ig = np.full(m, integ, np.bool_)
            if load:
                out[idx] = kernels.fused_sse_load(x, params, P[:, 8], a1, a2, d, ig, ts,
                                                  np.ascontiguousarray(freq_all[idx]), integ, yv, tr,
                                                  float(stage.gain_sign))
            else:
                E = _time_column(ts, n, integ)
                out[idx] = kernels.fused_sse(x, params, P[:, 8], a1, a2, d, ig, ts, E, yv, tr,
                                             float(stage.gain_sign))
    return out


def rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e)))) if e.size else float("nan")


def effective_n(e: np.ndarray, max_lag: int | None = None) -> float:
    """Effective number of independent samples of a residual (integrated autocorrelation time).

    Sums the autocorrelation until it first drops below 0.05 (Sokal-style window).
    """
    e = np.asarray(e, float) - float(np.mean(e))
    n = e.shape[0]
    if n < 8:
        return float(max(n, 1))
    var = float(e @ e)
    if var <= 0:
        return float(n)
    max_lag = min(n // 4, 500) if max_lag is None else max_lag
    f = np.fft.rfft(e, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[: max_lag + 1] / var
    tau = 1.0
    for k in range(1, max_lag + 1):
        if ac[k] < 0.05:
            break
        tau += 2.0 * ac[k]
    return float(max(min(n / tau, n), 5.0))
