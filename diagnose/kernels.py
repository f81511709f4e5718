"""The compiled kernels (diagnose/csrc, built by pip as the extension ``diagnose._kernels``).

The stiction model's valve step is written once, in C (``diagnose/csrc/valve_step.h``); every
kernel below runs it: many candidate valves over one input (`valve_run`), the output-error scoring
of valve x process candidates (`score`), the augmented model of `stiction explain` (`fused_sse`, and
`fused_sse_load` with each candidate's own load period),
and one sample at a time for the simulator (`ValveState`). The library carries vector variants
for the x86-64 baseline, AVX2 and AVX-512 and uses the widest the CPU supports (`isa`); every
variant returns the same numbers.

These are thin wrappers: they check shapes and pass pointers. The public, documented entry points
are `diagnose.stiction_model`, `diagnose.process_model`, `diagnose.objective` and
`diagnose.physics.valve`.
"""

from __future__ import annotations

import ctypes
import importlib.util

import numpy as np

from .errors import StictionError

ABI = 8


class KernelsMissingError(StictionError, ImportError):
    """The compiled kernels are not built (the package was not installed with pip)."""


def _load() -> ctypes.CDLL:
    spec = importlib.util.find_spec("diagnose._kernels")
    if spec is None or spec.origin is None:
        raise KernelsMissingError("the compiled kernels (diagnose._kernels) are missing: install the package "
                                  "with `pip install -e .` (or run scripts/setup.sh), which builds them")
    lib = ctypes.CDLL(spec.origin)
    if lib.kernels_abi() != ABI:
        raise KernelsMissingError(f"the compiled kernels at {spec.origin} are out of date (ABI "
                                  f"{lib.kernels_abi()}, expected {ABI}): reinstall with `pip install -e .`")
    return lib


_P = ctypes.c_void_p
_I = ctypes.c_int64
_D = ctypes.c_double
_C = ctypes.c_int
_lib = _load()
for _name, _args, _res in (
    ("valve_run", [_P, _I, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _D, _P, _I], None),
    ("score", [_P, _I, _P, _I, _P, _I, _C, _D, _D, _P, _P, _P, _I, _P, _D, _P, _D], _C),
    ("fused_sse", [_P, _I, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _D, _P, _I,
                   _P, _P, _D, _P], _C),
    ("fused_sse_load", [_P, _I, _I, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _P, _D, _P,
                        _C, _P, _P, _D, _P], _C),
    ("valve_step1", [_P, _P, _D], _D),
    ("valve_start1", [_P, _P, _D, _D, _D, _D], _D),
    ("valve_friction1", [_P, _D, _P], None),
    ("lag_filter", [_P, _I, _D, _D, _I, _C, _D, _P], None),
    ("hp_filter_2d", [_P, _I, _I, _I, _D, _P], None),
    ("sosfilt", [_P, _I, _P, _I, _P], None),
    ("peak_prominences", [_P, _I, _P, _P], _I),
    ("kernels_isa", [], _C),
    ("kernels_max_isa", [], _C),
    ("kernels_set_isa", [_C], _C),
    ("kernels_isa_name", [_C], ctypes.c_char_p),
):
    _fn = getattr(_lib, _name)
    _fn.argtypes = _args
    _fn.restype = _res


def isa() -> str:
    """The instruction-set variant the vector kernels use, e.g. ``"avx512 (8 lanes)"``."""
    return _lib.kernels_isa_name(_lib.kernels_isa()).decode()


def set_isa(level: int | None) -> str:
    """Use variant ``level`` (0 baseline, 1 AVX2, 2 AVX-512; None: the widest the CPU has), capped
    at what the CPU supports; returns the variant now in use. For tests and benchmarks."""
    _lib.kernels_set_isa(_lib.kernels_max_isa() if level is None else int(level))
    return isa()


def lanes() -> int:
    """Doubles per vector in the variant in use (2 baseline, 4 AVX2, 8 AVX-512): how many
    independent jobs one pass of a kernel scores for about the price of one."""
    return (2, 4, 8)[int(_lib.kernels_isa())]


def max_isa_level() -> int:
    return int(_lib.kernels_max_isa())


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _ptr(a: np.ndarray) -> int:
    return a.__array_interface__["data"][0]


def valve_run(x, S_up, J_up, S_dn, J_dn, dS, dJ, f0, a_lag, y0, xs0, ts_s: float,
              out: np.ndarray, *, t0=None, tw=None) -> np.ndarray:
    """m candidate valves over the input x (all parameter arrays of length m) into out (m, n).

    Per candidate: stiction opening (S_up, J_up) and closing (S_dn, J_dn), % of span; drift dS, dJ
    per second, from t0 seconds into the record for tw seconds (None: from the start, for ever; a
    tw of one sample period is a step of dS ts at t0); starting direction f0; actuator lag pole
    a_lag (0: none); start state y0 / xs0 (NaN: at rest at x[0]). out must be C-contiguous float64
    of shape (m, n).
    """
    x = _f64(x)
    arrs = [_f64(a) for a in (S_up, J_up, S_dn, J_dn, dS, dJ)]
    win = [None if a is None else _f64(a) for a in (t0, tw)]
    rest = [_f64(a) for a in (f0, a_lag, y0, xs0)]
    m, n = arrs[0].shape[0], x.shape[0]
    if any(a.shape != (m,) for a in arrs + rest + [w for w in win if w is not None]) or out.shape != (m, n) \
            or out.dtype != np.float64 or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError("valve_run: inconsistent shapes")
    if m and n:
        _lib.valve_run(_ptr(x), n, m, *(_ptr(a) for a in arrs), *(None if w is None else _ptr(w) for w in win),
                       *(_ptr(a) for a in rest), float(ts_s), _ptr(out), n)
    return out


class ScoreData:
    """The record side of `score`, prepared once: the valve input x, the weights w, the weighted data
    yw, the weighted orthonormal load basis Qw (n x K) and Qty, the residual sum of squares after the
    basis yyp, the noise prefilter's pole ahp (< 0: none), the sample period and a fixed gain (NaN:
    free). Holds its arrays (read-only) and their addresses, so a call passes pointers only."""

    __slots__ = ("x", "w", "yw", "Qw", "Qty", "yyp", "ahp", "ts_s", "gfix", "n", "K", "_args")

    def __init__(self, x, w, yw, Qw, Qty, yyp: float, ahp: float, ts_s: float, gfix: float) -> None:
        self.x, self.w, self.yw, self.Qw, self.Qty = (_f64(a) for a in (x, w, yw, Qw, Qty))
        self.n = self.x.shape[0]
        self.K = self.Qw.shape[1]
        if not (self.w.shape[0] == self.yw.shape[0] == self.Qw.shape[0] == self.n and self.Qty.shape[0] == self.K):
            raise ValueError("ScoreData: inconsistent shapes")
        self.yyp, self.ahp, self.ts_s, self.gfix = float(yyp), float(ahp), float(ts_s), float(gfix)
        self._args = (_ptr(self.x), self.n, _ptr(self.w), _ptr(self.yw), _ptr(self.Qw), self.K, _ptr(self.Qty))


def score(data: ScoreData, valves: np.ndarray, structs: np.ndarray,
          paired: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Output-error SSE and gain, each (m, P), of m valve candidates x P process structures.

    ``valves`` is (5, m): S, J, f0 and the start state y0, xs0 (NaN: at rest at the first input;
    see `valve_run`); ``structs`` is (4, P): lag poles a1, a2 (< 0: first order), dead
    time in samples, integrator (0/1); both C-contiguous float64. See ``score`` in
    diagnose/csrc/kernels_lanes.h; `diagnose.objective.Objective` prepares the arguments.
    ``paired``: P == m and only valve i with structure i is scored; SSE and gain are then (m,).
    The kernel keeps its scratch memory (a record's valve rows) per thread between calls.
    """
    m = valves.shape[1]
    P = structs.shape[1]
    if valves.shape[0] != 5 or structs.shape[0] != 4 or valves.dtype != np.float64 or structs.dtype != np.float64 \
            or not valves.flags.c_contiguous or not structs.flags.c_contiguous or (paired and P != m):
        raise ValueError("score: valves must be (5, m) and structs (4, P) (P = m when paired), "
                         "C-contiguous float64")
    out = np.empty((2, m) if paired else (2, m, P))
    if m and P:
        x, n, w, yw, Qw, K, Qty = data._args
        rc = _lib.score(x, n, _ptr(valves), m, _ptr(structs), P, int(paired), data.ts_s, data.ahp, w, yw, Qw, K,
                        Qty, data.yyp, _ptr(out), data.gfix)
        if rc != 0:
            raise MemoryError("score: out of memory")
    return out[0], out[1]


#: Columns of the fused kernels' per-candidate parameter rows (`fused_sse`).
PARAM_COLUMNS = 12


def fused_sse(x, params: np.ndarray, cc, a1, a2, d, integ, ts_s: float, E, y, w, sgn: float) -> np.ndarray:
    """Training SSE of m augmented models (see ``fused_sse`` in diagnose/csrc/kernels.c).

    ``params`` is (m, 12): S_up, J_up, S_dn, J_dn, dS, dJ, the drift's start t0 and length tw
    (seconds; 0 and inf: from the start, for ever), f0, a_lag, y0, xs0.
    """
    x, y, w, E = _f64(x), _f64(y), _f64(w), _f64(E)
    cols = [np.ascontiguousarray(params[:, j], dtype=np.float64) for j in range(PARAM_COLUMNS)]
    cc, a1, a2 = _f64(cc), _f64(a1), _f64(a2)
    d = np.ascontiguousarray(d, dtype=np.int64)
    ib = np.ascontiguousarray(integ, dtype=np.bool_).view(np.uint8)
    m, n = cols[0].shape[0], x.shape[0]
    q = E.shape[1]
    if y.shape[0] != n or w.shape[0] != n or E.shape[0] != n or any(a.shape[0] != m for a in (cc, a1, a2, d, ib)):
        raise ValueError("fused_sse: inconsistent shapes")
    out = np.empty(m)
    if m and n:
        rc = _lib.fused_sse(_ptr(x), n, m, *(_ptr(c) for c in cols), _ptr(cc), _ptr(a1), _ptr(a2), _ptr(d),
                            _ptr(ib), float(ts_s), _ptr(E), q, _ptr(y), _ptr(w), float(sgn), _ptr(out))
        if rc != 0:
            raise MemoryError("fused_sse: out of memory or too many extra columns")
    return out


def fused_sse_load(x, params: np.ndarray, cc, a1, a2, d, integ, ts_s: float, wload, with_t: bool, y, w,
                   sgn: float) -> np.ndarray:
    """`fused_sse` with each candidate's own sinusoidal load: the extra columns are [t] (``with_t``)
    and sin(w t), cos(w t) with ``w = wload[i]`` rad/s (see ``fused_sse_load`` in kernels.c)."""
    x, y, w = _f64(x), _f64(y), _f64(w)
    cols = [np.ascontiguousarray(params[:, j], dtype=np.float64) for j in range(PARAM_COLUMNS)]
    cc, a1, a2, wl = _f64(cc), _f64(a1), _f64(a2), _f64(wload)
    d = np.ascontiguousarray(d, dtype=np.int64)
    ib = np.ascontiguousarray(integ, dtype=np.bool_).view(np.uint8)
    m, n = cols[0].shape[0], x.shape[0]
    if y.shape[0] != n or w.shape[0] != n or any(a.shape[0] != m for a in (cc, a1, a2, d, ib, wl)):
        raise ValueError("fused_sse_load: inconsistent shapes")
    out = np.empty(m)
    if m and n:
        rc = _lib.fused_sse_load(_ptr(x), n, m, *(_ptr(c) for c in cols), _ptr(cc), _ptr(a1), _ptr(a2), _ptr(d),
                                 _ptr(ib), float(ts_s), _ptr(wl), int(bool(with_t)), _ptr(y), _ptr(w), float(sgn),
                                 _ptr(out))
        if rc != 0:
            raise MemoryError("fused_sse_load: out of memory")
    return out


def lag_filter(u, a1: float, a2: float, d: int, integ: bool, ts_s: float) -> np.ndarray:
    """Unit-gain lags (a2 < 0: first order), dead time d samples and optional integrator of u."""
    u = _f64(u)
    if int(d) < 0:
        raise ValueError("lag_filter: the dead time must be >= 0 samples")
    z = np.empty(u.shape[0])
    if u.shape[0]:
        _lib.lag_filter(_ptr(u), u.shape[0], float(a1), float(a2), int(d), 1 if integ else 0, float(ts_s),
                        _ptr(z))
    return z


def hp_filter(v, a: float) -> np.ndarray:
    """``(1 - q^-1) / (1 - a q^-1)`` along axis 0 (1-D or 2-D), starting at rest at the first sample."""
    arr = _f64(v)
    one = arr.ndim == 1
    if one:
        arr = arr[:, None]
    n, m = arr.shape
    out = np.empty((n, m))
    if n and m:
        _lib.hp_filter_2d(_ptr(arr), n, m, m, float(a), _ptr(out))
    return out[:, 0] if one else out


class ValveState:
    """One valve stepped one sample at a time (the simulators' valves), by the compiled step.

    The valve of `valve_run` for one candidate: stiction opening (``S_up``, ``J_up``) and closing
    (``S_dn``, ``J_dn``), % of span (>= 0); drift ``dS``, ``dJ`` per second from ``drift_from_s``
    for ``drift_for_s`` seconds (one sample period: a step); actuator lag pole ``a_lag`` (0: none);
    sample period ``ts_s``. `step` returns the stem position after the lag.
    """

    __slots__ = ("state", "params", "_sp", "_pp")

    def __init__(self, S_up: float, J_up: float, S_dn: float, J_dn: float, *, dS: float = 0.0, dJ: float = 0.0,
                 drift_from_s: float = 0.0, drift_for_s: float = float("inf"), a_lag: float = 0.0,
                 ts_s: float = 1.0) -> None:
        self.state = np.zeros(8)
        self.params = np.array([S_up, J_up, S_dn, J_dn, dS, dJ, drift_from_s, drift_for_s, a_lag, ts_s],
                               dtype=np.float64)
        self._sp = ctypes.c_void_p(self.state.ctypes.data)
        self._pp = ctypes.c_void_p(self.params.ctypes.data)

    def start(self, x0_pct: float, f0: float, y0_pct: float = float("nan"),
              xs0_pct: float = float("nan")) -> float:
        return _lib.valve_start1(self._sp, self._pp, float(x0_pct), float(f0), float(y0_pct), float(xs0_pct))

    def step(self, x_pct: float) -> float:
        return _lib.valve_step1(self._sp, self._pp, float(x_pct))

    @property
    def stuck(self) -> bool:
        return bool(self.state[2])

    @property
    def direction(self) -> float:
        return float(self.state[4])


def valve_friction(S_up: float, J_up: float, S_dn: float, J_dn: float, dS: float, dJ: float, drift_from_s: float,
                   drift_for_s: float, t_s: float) -> tuple[float, float, float, float]:
    """(S_up, J_up, S_dn, J_dn) ``t_s`` seconds after the first sample under the drift schedule the
    valve kernels run (see `ValveState`); ``t_s`` may be infinite (after a drift window or step)."""
    p = np.array([S_up, J_up, S_dn, J_dn, dS, dJ, drift_from_s, drift_for_s], dtype=np.float64)
    out = np.empty(4)
    _lib.valve_friction1(_ptr(p), float(t_s), _ptr(out))
    return float(out[0]), float(out[1]), float(out[2]), float(out[3])


def sosfilt(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Second-order sections ``sos`` (k, 6) over ``x`` from section states ``zi`` (k, 2): the
    filtered signal and the final states (as `scipy.signal.sosfilt` with ``zi``)."""
    sos, y, z = _f64(sos), np.array(x, dtype=np.float64), np.array(zi, dtype=np.float64)
    if sos.ndim != 2 or sos.shape[1] != 6 or z.shape != (sos.shape[0], 2) or y.ndim != 1:
        raise ValueError("sosfilt: sos must be (k, 6), zi (k, 2) and x 1-D")
    _lib.sosfilt(_ptr(sos), sos.shape[0], _ptr(y), y.shape[0], _ptr(z))
    return y, z


def peak_prominences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every local maximum of ``x`` (a flat top at its middle) and its prominence over the whole
    record, as `scipy.signal.find_peaks` and `scipy.signal.peak_prominences` define them."""
    x = _f64(x)
    if x.ndim != 1:
        raise ValueError("peak_prominences: x must be 1-D")
    peaks = np.empty(max(x.shape[0], 1), dtype=np.int64)
    prom = np.empty(max(x.shape[0], 1), dtype=np.float64)
    m = int(_lib.peak_prominences(_ptr(x), x.shape[0], _ptr(peaks), _ptr(prom))) if x.shape[0] else 0
    return peaks[:m].copy(), prom[:m].copy()
