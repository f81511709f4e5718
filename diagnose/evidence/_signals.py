"""Signal conditioning shared by the evidence tests, written once.

Everything here works on plain float arrays, one value per sample; periods and lags are in
samples (the tests convert to seconds only for what they report). `Prepared` validates a record
once and caches what several tests need: detrended signals, the oscillation period and regularity
of each, the half-cycle segmentation, noise levels.

The oscillation measure is Thornhill, Huang and Zhang's (2003) autocorrelation zero-crossing test,
as in `diagnose.oscillation`, but read over lags up to three quarters of the record so that a
window of about three cycles still gives a period: the evidence tests judge short plant windows.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from .. import kernels
from ..oscillation import acf
from ..plain import op_amount

MIN_SAMPLES = 32          # below this no test judges anything
MIN_CYCLES = 2.0          # oscillation tests need at least this many periods in the record
MIN_INTERVALS = 3         # ACF zero-crossing intervals needed for a regularity figure
REGULARITY = 1.0          # Thornhill et al. (2003): r > 1 is a regular oscillation
MIN_PERIOD = 4.0          # samples; faster "oscillations" are noise at this sampling


def detrend(x: np.ndarray) -> np.ndarray:
    """Remove the mean and the least-squares straight line."""
    n = x.shape[0]
    if n < 3:
        return x - (x.mean() if n else 0.0)
    t = np.arange(n, dtype=float) - 0.5 * (n - 1)
    slope = float(t @ x) / float(t @ t)
    return x - x.mean() - slope * t


@lru_cache(maxsize=256)
def _butter(order: int, edges: tuple[float, ...], btype: str) -> np.ndarray:
    """Digital Butterworth filter as second-order sections (rows b0 b1 b2 1 a1 a2).

    ``edges`` are fractions of Nyquist; ``btype`` "lowpass" (one edge) or "bandpass" (two). The
    analogue prototype's poles are pre-warped, moved to the band and mapped by the bilinear
    transform, as in scipy.signal.butter; sections pair conjugate poles, all zeros sit at -1
    (low-pass) or one at +1 and one at -1 (band-pass), and the gain goes to the first section.
    Designs are kept: designing costs more than filtering a plant window.
    """
    fs2 = 4.0                                          # 2 fs with fs = 2: edges are in Nyquist units
    warped = [fs2 * np.tan(np.pi * w / 2.0) for w in edges]
    proto = -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))
    if btype == "lowpass":
        p_s = proto * warped[0]
        k_s = warped[0] ** order
        z_count = 0
    else:
        bw = warped[1] - warped[0]
        wo2 = warped[0] * warped[1]
        p_lp = proto * bw / 2.0
        root = np.sqrt(p_lp ** 2 - wo2)
        p_s = np.concatenate([p_lp + root, p_lp - root])
        k_s = bw ** order
        z_count = order                                # zeros at s = 0, i.e. z = +1
    p_z = (fs2 + p_s) / (fs2 - p_s)
    n_poles = p_z.shape[0]
    # gain of the bilinear map: zeros at s = 0 contribute fs2 each, the rest map to z = -1
    k_z = k_s * float(np.real(fs2 ** z_count / np.prod(fs2 - p_s)))
    upper = p_z[np.imag(p_z) > 0]
    upper = upper[np.argsort(np.abs(upper))]          # the pole nearest the unit circle last
    n_plus = z_count
    rows = []
    for p in upper:
        if n_plus >= 2:
            b = [1.0, -2.0, 1.0]
            n_plus -= 2
        elif n_plus == 1:
            b = [1.0, 0.0, -1.0]
            n_plus -= 1
        else:
            b = [1.0, 2.0, 1.0]
        rows.append(b + [1.0, -2.0 * p.real, abs(p) ** 2])
    if len(rows) * 2 != n_poles:
        raise ValueError("Butterworth design: an odd order is not supported")
    sos = np.asarray(rows, dtype=float)
    sos[0, :3] *= k_z
    return sos


def _sos_zi(sos: np.ndarray) -> np.ndarray:
    """Each section's state for a unit step in steady state (scipy.signal.sosfilt_zi)."""
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for i, (b0, b1, b2, _, a1, a2) in enumerate(sos):
        # (I - A^T) z = b[1:] - a[1:] b0 for the section's companion matrix A
        m = np.array([[1.0 + a1, -1.0], [a2, 1.0]])
        zi[i] = scale * np.linalg.solve(m, np.array([b1 - a1 * b0, b2 - a2 * b0]))
        scale *= (b0 + b1 + b2) / (1.0 + a1 + a2)
    return zi


def _sosfiltfilt(sos: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Forward-backward filtering with odd extension at both ends (scipy.signal.sosfiltfilt)."""
    edge = 3 * (2 * sos.shape[0] + 1)
    ext = np.concatenate([2.0 * x[0] - x[edge:0:-1], x, 2.0 * x[-1] - x[-2:-(edge + 2):-1]])
    zi = _sos_zi(sos)
    y, _ = kernels.sosfilt(sos, ext, zi * ext[0])
    y, _ = kernels.sosfilt(sos, y[::-1], zi * y[-1])
    return y[::-1][edge:-edge]


def _edge(f: float) -> float:
    """A band edge as a fraction of Nyquist, rounded to 3 significant digits (for the cache)."""
    return float(f"{max(f, 1e-4) / 0.5:.3g}")


def _too_short(n: int, order: int, bands: int = 1) -> bool:
    # sosfiltfilt pads 3 (2 sections + 1) samples at each end and needs more samples than that
    sections = bands * ((order + 1) // 2)
    return n <= 3 * (2 * sections + 1)


def lowpass(x: np.ndarray, fc: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass; ``fc`` in cycles per sample (Nyquist is 0.5)."""
    if fc >= 0.45 or _too_short(x.shape[0], order):
        return x.copy()
    return _sosfiltfilt(_butter(order, (_edge(fc),), "lowpass"), x)


def bandpass(x: np.ndarray, f_lo: float, f_hi: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth band-pass, edges in cycles per sample."""
    if _too_short(x.shape[0], order, bands=2):
        return x.copy()
    f_hi = min(f_hi, 0.45)
    if f_lo <= 1e-4:
        return lowpass(x, f_hi, order)
    if f_lo >= f_hi:
        return x - x.mean()
    return _sosfiltfilt(_butter(order, (_edge(f_lo), _edge(f_hi)), "bandpass"), x)


def noise_sd(x: np.ndarray) -> float:
    """Standard deviation of the white-noise part, from the first differences (robust)."""
    if x.shape[0] < 3:
        return 0.0
    d = np.diff(x)
    s = float(np.median(np.abs(d - np.median(d)))) * 1.4826 / np.sqrt(2.0)
    if s <= 0:   # held or quantised samples: most differences are exactly zero
        s = float(np.std(d)) / np.sqrt(2.0)
    return s


def crossings(x: np.ndarray) -> np.ndarray:
    """Interpolated positions (fractional sample index) where ``x`` changes sign."""
    s = np.signbit(x)
    k = np.flatnonzero(s[1:] != s[:-1])
    a, b = x[k], x[k + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(a != b, a / (a - b), 0.0)
    return k + frac


@dataclass(frozen=True)
class Oscillation:
    """Period and regularity of one signal (ACF zero-crossing test).

    ``period`` is in samples (None when the ACF has fewer than two zero crossings); ``regularity``
    is Thornhill's r (0 when fewer than two intervals); ``intervals`` how many ACF half-period
    intervals were read; ``cycles`` the record length in periods.
    """

    period: float | None
    regularity: float
    intervals: int
    cycles: float

    @property
    def regular(self) -> bool:
        """A regular oscillation of at least two cycles: the oscillation tests judge."""
        return self.problem("") is None

    def problem(self, what: str) -> tuple[str, str] | None:
        """``(reason, sentence)`` when this is no regular oscillation of at least two cycles."""
        if self.period is None or self.period < MIN_PERIOD:
            return "no_oscillation", f"{what} shows no oscillation (its autocorrelation does not cycle)."
        if self.cycles < MIN_CYCLES:
            return "too_few_cycles", (f"{what} holds only {self.cycles:.1f} periods of its oscillation; "
                                      f"the test needs {MIN_CYCLES:.0f}.")
        if self.intervals < MIN_INTERVALS or self.regularity <= REGULARITY:
            return "irregular_oscillation", (f"{what} does not oscillate regularly (regularity "
                                             f"{self.regularity:.2f}, needs > {REGULARITY:.0f}).")
        return None


def oscillation(x: np.ndarray) -> Oscillation:
    """Thornhill's ACF zero-crossing period and regularity of a detrended signal."""
    n = x.shape[0]
    if n < MIN_SAMPLES or not np.ptp(x) > 0:
        return Oscillation(None, 0.0, 0, 0.0)
    r = acf(x, max_lag=int(0.75 * n))
    pos = crossings(r)
    if pos.shape[0] < 2:
        return Oscillation(None, 0.0, 0, 0.0)
    # the ACF decays; its late crossings are noise
    half = np.diff(pos)[:10]
    period = 2.0 * float(np.mean(half))
    if half.shape[0] >= 2:
        sd = float(np.std(2.0 * half))
        reg = min(period / (3.0 * sd), 100.0) if sd > 0 else 100.0
    else:
        reg = 0.0
    return Oscillation(period, reg, int(half.shape[0]), n / period)


def half_cycles(x: np.ndarray, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Half-cycles of an oscillating, detrended signal as zero-crossing positions (fractional
    sample indices) ``(c_start, c_end)``; the samples of half-cycle i are those strictly inside.

    The boundaries are the zero crossings of the signal band-passed around its oscillation
    (1/3 to 3 times the oscillation frequency), so noise and slow wander do not add crossings.
    Half-cycles shorter than a quarter or longer than 2.5 times half the period are dropped
    (broken cycles); an asymmetric (saw-tooth) wave keeps its unequal halves.
    """
    f0 = 1.0 / period
    c = crossings(bandpass(x, f0 / 3.0, 3.0 * f0))
    if c.shape[0] < 2:
        empty = np.zeros(0)
        return empty, empty
    length = np.diff(c)
    keep = (length >= max(4.0, 0.125 * period)) & (length <= 1.25 * period)
    return c[:-1][keep], c[1:][keep]


def sample_range(c_start: np.ndarray, c_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and one-past-last sample index strictly inside each half-cycle."""
    return np.floor(c_start).astype(np.int64) + 1, np.ceil(c_end).astype(np.int64)


def segment_matrix(x: np.ndarray, start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-cycles as rows of a zero-padded matrix, and the mask of real samples."""
    length = end - start
    L = int(length.max()) if length.shape[0] else 0
    j = np.arange(L)
    mask = j[None, :] < length[:, None]
    idx = np.where(mask, start[:, None] + j[None, :], 0)
    return np.where(mask, x[idx], 0.0), mask


class Prepared:
    """A record checked once, with what several tests share computed on first use.

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,) or None
        Process variable, engineering units (None when there is none).
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; when it moves, the control error SP - PV replaces PV where a test reads the
        error (Horch, Choudhury, Singhal-Salsbury).
    op_units : str
        OP's units (`diagnose.identification.Identification.op_units`): ``"% of span"``, or
        ``"OP units"`` / ``"fraction of span"`` for an OP logged otherwise. Only the notes that
        give an amount of OP travel read it (`op_amount`).
    """

    def __init__(self, op, pv, ts_s, sp=None, op_units: str = "% of span") -> None:
        self.op_units = op_units
        self.problem: tuple[str, str] | None = None
        self.pv_ok, self.pv_reason = True, ""
        self.cache: dict = {}       # results several tests share (e.g. one curve fit of OP)
        try:
            self.ts_s = float(ts_s)
        except (TypeError, ValueError):
            self.ts_s = float("nan")
        self.op = _as_array(op)
        self.pv = _as_array(pv) if pv is not None else None
        self.sp = _as_array(sp) if sp is not None else None
        self.n = self.op.shape[0]
        if not (np.isfinite(self.ts_s) and self.ts_s > 0):
            self.problem = ("bad_sample_period", f"The sample period must be a positive number of seconds "
                            f"(got {ts_s!r}).")
        elif self.op.ndim != 1:
            self.problem = ("bad_shape", f"OP must be one-dimensional (got shape {self.op.shape}).")
        elif self.n < MIN_SAMPLES:
            self.problem = ("too_short", f"The record has {self.n} samples; the tests need at least {MIN_SAMPLES}.")
        elif not np.all(np.isfinite(self.op)):
            bad = int(np.count_nonzero(~np.isfinite(self.op)))
            self.problem = ("non_finite", f"OP has {bad} missing or non-finite samples; clean or cut them first.")
        elif not np.ptp(self.op) > 1e-9 * max(1.0, float(np.max(np.abs(self.op)))):
            self.problem = ("op_flat", f"OP never moves (constant {float(self.op[0]):.4g}); a valve whose "
                            "command does not move cannot show stiction (manual or saturated?).")
        if self.pv is None:
            self.pv_ok, self.pv_reason = False, "no PV was given"
        elif self.pv.shape != self.op.shape:
            self.pv_ok, self.pv_reason = False, f"PV has {self.pv.shape[0]} samples but OP has {self.n}"
        else:
            self.pv_ok, self.pv_reason = pv_usable(self.pv)
        if self.sp is not None and (self.sp.shape != self.op.shape or not np.all(np.isfinite(self.sp))):
            self.sp = None      # an unusable setpoint is ignored: the tests fall back to PV

    # -- signals -----------------------------------------------------------------------------
    def op_amount(self, v: float) -> str:
        """An amount of OP travel in words, in OP's own units (`diagnose.plain.op_amount`)."""
        return op_amount(v, self.op_units)

    @cached_property
    def op_d(self) -> np.ndarray:
        return detrend(self.op)

    @cached_property
    def pv_d(self) -> np.ndarray:
        return detrend(self.pv)

    @cached_property
    def sp_moves(self) -> bool:
        return self.sp is not None and bool(np.ptp(self.sp) > 0)

    @cached_property
    def err_d(self) -> np.ndarray:
        """Detrended control error SP - PV (just -PV when the setpoint does not move)."""
        return detrend(self.sp - self.pv) if self.sp_moves else -self.pv_d

    @property
    def err_name(self) -> str:
        return "the control error SP - PV" if self.sp_moves else "PV"

    @cached_property
    def _osc(self) -> dict[str, Oscillation]:
        return {}

    def osc(self, name: str) -> Oscillation:
        """Oscillation of ``"op"``, ``"pv"`` or ``"err"`` (detrended)."""
        if name not in self._osc:
            self._osc[name] = oscillation(getattr(self, name + "_d"))
        return self._osc[name]

    @cached_property
    def _halves(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        return {}

    def halves(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Half-cycle boundaries (fractional crossing positions) of ``"op"``, ``"pv"`` or ``"err"``;
        needs a period."""
        if name not in self._halves:
            o = self.osc(name)
            self._halves[name] = half_cycles(getattr(self, name + "_d"), o.period)
        return self._halves[name]

    @cached_property
    def scale(self) -> float:
        """Samples over which to smooth before taking derivatives: a 24th of the oscillation
        period of OP (or of the error), or, when neither oscillates, a quarter of the lag at which
        OP's autocorrelation falls to one half."""
        for name in ("op", "err") if self.pv_ok else ("op",):
            o = self.osc(name)
            if o.period is not None and o.period >= MIN_PERIOD:
                return max(1.0, o.period / 24.0)
        r = acf(self.op_d, max_lag=self.n // 2)
        k = np.flatnonzero(r < 0.5)
        return max(1.0, (float(k[0]) if k.shape[0] else self.n / 2) / 4.0)

    @property
    def smooth_fc(self) -> float:
        return 0.5 / max(1.0, self.scale)

    @cached_property
    def op_s(self) -> np.ndarray:
        return lowpass(self.op, self.smooth_fc)

    @cached_property
    def pv_s(self) -> np.ndarray:
        return lowpass(self.pv, self.smooth_fc)


def smoothed_noise_sd(raw: np.ndarray, smooth: np.ndarray, fc: float) -> tuple[float, float]:
    """``(sd of the smoothed signal's noise, sd of its per-sample change)`` for white noise of
    the robust level seen in ``raw - smooth``, after a low-pass at ``fc`` cycles per sample."""
    r = raw - smooth
    sd = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    if sd <= 0:
        sd = float(np.std(r))
    fc = min(fc, 0.5)
    # white noise through an ideal low-pass: variance times 2 fc; its derivative (2 pi)^2 2 fc^3 / 3
    return sd * np.sqrt(2.0 * fc), sd * 2.0 * np.pi * np.sqrt(2.0 * fc ** 3 / 3.0)


def _as_array(x) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return np.zeros(0)
    return a.reshape(-1) if a.ndim == 0 else a


def pv_usable(pv, *, min_samples: int = MIN_SAMPLES) -> tuple[bool, str]:
    """Is the PV usable for the PV-based tests? ``(ok, reason)``; the reason is empty when ok.

    PV is unusable when it is missing, too short, non-finite in more than 5 % of the samples,
    constant, frozen (one exactly flat run over half the record, or moving in fewer than 5 % of
    the samples), or on three distinct values or fewer (an on/off or broken signal). The
    coordinator then judges from OP alone (`diagnose.evidence.op_shape`).
    """
    a = _as_array(pv)
    if a.ndim != 1 or a.shape[0] == 0:
        return False, "no PV samples"
    n = a.shape[0]
    if n < min_samples:
        return False, f"PV has only {n} samples"
    fin = np.isfinite(a)
    if np.count_nonzero(~fin) > 0.05 * n:
        return False, f"PV is missing or non-finite in {100 * np.mean(~fin):.0f} % of the samples"
    a = a[fin]
    scale = max(1.0, float(np.max(np.abs(a))))
    if not np.ptp(a) > 1e-9 * scale:
        return False, f"PV is constant ({float(a[0]):.4g}) over the whole record: a dead or disconnected signal"
    moving = np.diff(a) != 0
    if np.mean(moving) < 0.05:
        return False, (f"PV changes in only {100 * np.mean(moving):.1f} % of the samples: a frozen or dead "
                       "transmitter or historian tag")
    # longest exactly flat run
    m = np.concatenate([[False], ~moving, [False]]).astype(np.int8)
    d = np.diff(m)
    runs = np.flatnonzero(d == -1) - np.flatnonzero(d == 1)
    if runs.shape[0] and runs.max() + 1 >= 0.5 * n:
        return False, f"PV is frozen at one value for {int(runs.max()) + 1} of {n} samples"
    levels = np.unique(a).shape[0]
    if levels <= 3:
        return False, f"PV takes only {levels} distinct values: an on/off or broken signal"
    return True, ""
