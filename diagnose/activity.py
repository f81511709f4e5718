"""Valve activity: how far the valve travels and how often it reverses, per day of record.

Loop-monitoring tools rank valves by their travel and reversals beside variability, oscillation
and stiction: a valve that travels far and reverses often wears its packing and seat, and a
sticky valve in a limit cycle reverses every half period. This module counts both from the
controller output (OP, what the valve is asked to do) and, where a positioner reports it, the stem
position (MV, what the valve did), and the share of time the loop ran in automatic where the
record carries the controller's mode.

Measurement noise must not count as travel: a raw sum of ``|diff(OP)|`` on a noisy OP grows with
the noise, not with the valve's movement, and every noise wiggle is a "reversal". Movement is
therefore counted through a hysteresis band (`noise_band_pct`) estimated from the signal itself;
see `valve_activity`. Pure computation: numpy arrays in, a frozen dataclass out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import DataError


def kept_digits(v: float | None) -> float | None:
    """A rate as the JSON, the summary and the report keep it: 4 significant digits (more would
    be noise); None for None or a value that is not finite."""
    if v is None or not math.isfinite(v):
        return None
    return float(f"{v:.4g}")


#: Seconds per day: travel and reversals are given per day of record.
DAY_S = 86_400.0

#: The hysteresis band is this many times the robust noise standard deviation of the signal:
#: white noise alone retreats from its running extreme by 6 sigma now and then over a long record
#: and by 8 sigma practically never (tests/test_activity.py), while a movement of a few % of span
#: on an OP with 0.1 % noise is still counted in full.
BAND_SIGMAS = 8.0

#: A band is never narrower than this fraction of the signal's magnitude: floating-point rounding
#: (1e-15 of the value) is not movement.
_REL_FLOOR = 1e-9

__all__ = ["ValveActivity", "valve_activity", "noise_sigma", "hysteresis_turns", "BAND_SIGMAS", "DAY_S"]


@dataclass(frozen=True)
class ValveActivity:
    """How far and how often a valve moves, per day of record.

    Attributes
    ----------
    travel_pct_per_day : float
        Total distance OP travelled, in % of valve span per day of record (OP's own units per day
        when OP is not in % of span), with movement inside the noise band not counted (see
        `valve_activity`). 100 % per day is one full stroke's worth of travel each day; a valve
        cycling with amplitude a (% of span) and period T travels about ``4 a * 86400 / T`` % per day.
    reversals_per_day : float
        Direction changes of OP by more than the noise band, per day of record; a loop oscillating
        with period T reverses ``2 * 86400 / T`` times a day.
    mv_travel_pct_per_day, mv_reversals_per_day : float or None
        The same for the recorded stem position (MV), with MV's own noise band: what the valve
        actually did (a sticky valve reverses less often than OP asks, and in jumps). None when no
        stem position is recorded.
    service_factor : float or None
        Share of the record, 0..1, in which the controller was in automatic (the mode signal said
        so), counted over the samples whose mode is known. None when the record carries no mode
        signal (or none of its values is known): the share cannot be told.
    days : float
        The record length the rates are per: samples x sample period, in days. Rates from a record
        of a few hours extrapolate a short window to a day; judge them by this.
    noise_band_pct : float
        The hysteresis band used for OP (% of span, or OP's units): 8 times OP's robust noise
        standard deviation (`noise_sigma`). Movements smaller than this are not counted.
    mv_noise_band_pct : float or None
        The band used for MV (None without MV).
    """

    travel_pct_per_day: float
    reversals_per_day: float
    days: float
    noise_band_pct: float
    mv_travel_pct_per_day: float | None = None
    mv_reversals_per_day: float | None = None
    mv_noise_band_pct: float | None = None
    service_factor: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types, rounded to 4 significant digits (`kept_digits`)."""
        r = kept_digits

        return {"travel_pct_per_day": r(self.travel_pct_per_day),
                "reversals_per_day": r(self.reversals_per_day),
                "mv_travel_pct_per_day": r(self.mv_travel_pct_per_day),
                "mv_reversals_per_day": r(self.mv_reversals_per_day),
                "service_factor": r(self.service_factor),
                "days": r(self.days),
                "noise_band_pct": r(self.noise_band_pct),
                "mv_noise_band_pct": r(self.mv_noise_band_pct)}


def noise_sigma(x: np.ndarray) -> float:
    """A robust estimate of the white measurement noise's standard deviation on a signal.

    From second differences, ``1.4826 * MAD(diff(x, 2)) / sqrt(6)``: a second difference of white
    noise of standard deviation sigma has standard deviation ``sqrt(6) sigma``, while the valve's own
    movement (ramps, triangles, slow curves) leaves second differences near zero except at its few
    turning points and steps, which the median ignores. 0 for a signal that is mostly held (a
    historian that stores only changes): such a signal has no noise to filter.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 3:
        return 0.0
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def _extrema(x: np.ndarray) -> np.ndarray:
    """The values at which a signal turns, with its first and last value: the samples held (no
    change) and the inside of monotone runs dropped, so the turns alternate up and down."""
    d = np.diff(x)
    keep = np.flatnonzero(d != 0.0)
    if keep.size == 0:
        return x[:1]
    # the value after each change: a monotone run's inside points have the same sign on both sides
    v = np.concatenate((x[:1], x[keep + 1]))
    s = np.sign(d[keep])
    turn = np.flatnonzero(s[1:] != s[:-1])  # v[turn + 1] is an extreme
    return np.concatenate((v[:1], v[turn + 1], v[-1:]))


def hysteresis_turns(x: np.ndarray, band: float) -> np.ndarray:
    """The turning points of a signal through a hysteresis band: the extremes from which the signal
    retreated by more than ``band`` (and the extreme it last reached), in order.

    A movement counts once the signal has moved more than ``band`` away from the last turning point
    in the new direction; wiggles within the band around a running extreme do not count. The first
    turning point is the start's lowest (highest) value before the first movement up (down) beyond
    the band. A signal that never moves by more than ``band`` has a single turning point.
    """
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return x
    e = _extrema(x).tolist()
    # the record is reduced to its alternating extremes (vectorised); the band is applied in one
    # pass over them, sequential by nature (each turn depends on the last)
    lo = hi = e[0]
    k = 0
    n = len(e)
    turns: list[float] = []
    direction = 0
    while k < n - 1:  # before the first movement beyond the band: track both ends
        k += 1
        v = e[k]
        if v > hi:
            hi = v
        elif v < lo:
            lo = v
        if hi - lo > band:
            if v == hi:
                turns.append(lo)
                direction = 1
            else:
                turns.append(hi)
                direction = -1
            break
    if direction == 0:
        return np.asarray([e[0]], dtype=float)
    for v in e[k + 1:]:
        if direction > 0:
            if v > hi:
                hi = v
            elif hi - v > band:
                turns.append(hi)
                direction = -1
                lo = v
        else:
            if v < lo:
                lo = v
            elif v - lo > band:
                turns.append(lo)
                direction = 1
                hi = v
    turns.append(hi if direction > 0 else lo)
    return np.asarray(turns, dtype=float)


#: On a quantised signal (values on a grid of step q) the band is at least this many steps: a
#: flicker by one level is the resolution's, not the valve's, while a move of two levels counts.
QUANT_STEPS = 1.5


def _travel(x: np.ndarray) -> tuple[float, int, float]:
    """(travel, reversals, band) of one signal over the record."""
    from .quality import quantum

    x = np.asarray(x, dtype=float)
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    band = max(BAND_SIGMAS * noise_sigma(x), _REL_FLOOR * max(scale, 1.0))
    q = quantum(x) if x.size > 2 else None
    if q is not None and band < QUANT_STEPS * q["step"]:
        # held at its levels, the signal's second differences are mostly zero, so its noise reads
        # as none and each flicker by one level would count as a reversal: where it turns back
        # after one level, the band is widened to drop such turns (a ramp sampled in equal steps
        # is on a grid too, but never turns by one step)
        turns = np.abs(np.diff(_extrema(x))) / q["step"]
        if np.any(np.abs(turns - 1.0) <= 0.02):
            band = QUANT_STEPS * q["step"]
    turns = hysteresis_turns(x, band)
    travel = float(np.sum(np.abs(np.diff(turns)))) if turns.size > 1 else 0.0
    return travel, max(int(turns.size) - 2, 0), band


def _series(name: str, values: Any) -> np.ndarray:
    """One signal as a 1-D float array of finite values, or a one-line `DataError` saying why not:
    a gap would break the record into pieces whose travel does not add up, so it must be filled
    (or the record cut) by the caller, as the readers do."""
    try:
        x = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be numbers, one per sample") from None
    if x.ndim == 2 and 1 in x.shape:
        x = x.ravel()                   # one column (or row) of a table
    if x.ndim != 1:
        raise DataError(f"{name} must be one series of samples, got shape {x.shape}")
    if x.size == 0:
        raise DataError(f"{name} holds no samples")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise DataError(f"{name} has {bad.size} NaN/inf value(s) (the first at sample {int(bad[0])}); fill or "
                        "cut the gaps first (diagnose.read_loops does)")
    return x


def valve_activity(op_pct: Any, ts_s: float, *, mv_pct: Any = None, mode_auto: Any = None) -> ValveActivity:
    """Valve travel, reversals and (with a mode signal) service factor of one loop's record.

    Parameters
    ----------
    op_pct : array of float, shape (n,)
        Controller output, % of valve span, uniformly sampled.
    ts_s : float
        Sample period, seconds.
    mv_pct : array of float, shape (n,), optional
        Recorded stem position, % of span.
    mode_auto : array of bool or float, shape (n,), optional
        True (1) where the controller was in automatic, False (0) in manual, NaN where the mode is
        not known (before the mode signal's first sample, after a bad one); gives the service
        factor over the samples whose mode is known. Leave it out when the record carries no mode
        signal (the service factor is then None, not 1).

    Returns
    -------
    ValveActivity

    Raises
    ------
    DataError
        No samples, NaN/inf or more than one dimension in OP or MV, a sample period that is not a
        positive number, or MV / mode of another length.

    Notes
    -----
    Noise is kept out by a hysteresis band: OP's noise standard deviation sigma is estimated
    robustly from its sample-to-sample changes (`noise_sigma`: the median absolute deviation of its
    second differences, which the valve's ramps and turns hardly touch), and the band is
    ``8 sigma`` (`BAND_SIGMAS`). The record is reduced to its turning points through that band
    (`hysteresis_turns`): a reversal counts when the signal has retreated more than the band from
    its running extreme, and travel is the sum of the distances between successive turning points.
    On a noiseless signal the band is zero and travel is the total variation ``sum |diff(OP)|``
    exactly, reversals the number of direction changes; on a noisy one, noise neither adds its
    own wiggles to the travel nor multiplies the reversals, while a movement larger than the band
    is counted in full (its extremes are the noisy extremes, so travel reads high by about one noise
    width per turn). A movement smaller than the band is not counted at all: on a valve whose
    noise is large against its movements, travel reads low. MV gets its own band, from its own
    noise. The estimate assumes white noise: noise that was low-pass filtered before it was logged
    (correlated from sample to sample) has smaller second differences than its size, so part of
    it is counted as movement. An OP held at quantisation levels (every change a whole number of
    steps q) has mostly zero second differences, so its noise reads as none: where it turns back
    after a single level, its band is ``1.5 q`` (`QUANT_STEPS`), so that a flicker by one level is
    not a reversal (a move of two levels or more counts).

    The rates are per day of record (``n * ts_s / 86400`` days). Cost: a few vectorised passes and
    one loop over the turning points of the signal (a few ms for 10 000 samples).
    """
    op = _series("op_pct", op_pct)
    n = int(op.size)
    try:
        ts = float(ts_s)
    except (TypeError, ValueError):
        raise DataError(f"ts_s={ts_s!r}: the sample period must be a positive number of seconds") from None
    if isinstance(ts_s, (str, bytes)) or not (math.isfinite(ts) and ts > 0):
        raise DataError(f"ts_s={ts_s!r}: the sample period must be a positive number of seconds")
    days = n * ts / DAY_S
    per_day = 1.0 / days
    travel, rev, band = _travel(op)
    mv_travel = mv_rev = mv_band = None
    if mv_pct is not None:
        mv = _series("mv_pct", mv_pct)
        if mv.size != n:
            raise DataError(f"mv_pct has {mv.size} samples but op_pct has {n}")
        t, r, mv_band = _travel(mv)
        mv_travel, mv_rev = t * per_day, r * per_day
    sf = None
    if mode_auto is not None:
        try:
            auto = np.asarray(mode_auto, dtype=float)
        except (TypeError, ValueError):
            raise DataError("mode_auto must hold True/False (1/0) per sample, NaN where the mode is unknown; "
                            "map text states such as 'AUTO' to True first") from None
        if auto.ndim != 1 or auto.size != n:
            raise DataError(f"mode_auto has shape {auto.shape} but op_pct has {n} samples")
        known = np.isfinite(auto)
        if known.any():
            sf = float(np.count_nonzero(auto[known] >= 0.5)) / int(np.count_nonzero(known))
    return ValveActivity(travel_pct_per_day=travel * per_day, reversals_per_day=rev * per_day, days=days,
                         noise_band_pct=band, mv_travel_pct_per_day=mv_travel, mv_reversals_per_day=mv_rev,
                         mv_noise_band_pct=mv_band, service_factor=sf)
