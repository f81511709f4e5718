"""The checks a simulated record must pass before it enters the corpus, and what they measure.

A record that fails one is drawn again from a derived seed (`scenarios.make_loop`). Two
definitions of the corpus:

* ``"original"`` -- OP at 0 or 100 % for at most 5 % of the samples, PV finite and inside the
  transmitter's span, a sticky valve starting to move at least 3 times.
* ``"identifiable"`` -- every record is a loop a control engineer would recognise as running, and
  every sticky record can show its stiction in the data:

  - ``saturation``: OP at 0 or 100 % on at most `MAX_SATURATED` of the samples;
  - ``op_range``: OP's 1-99 % range at most `MAX_OP_RANGE_PCT` % of span (not cycling over the
    whole valve);
  - ``op_noise``: OP's own sample-to-sample noise (`op_noise`) at most `MAX_OP_NOISE_PCT` % of
    span (a controller that throws the valve around by several % on every sample from amplified
    measurement noise is not left running in a plant);
  - ``growing``: OP's swing does not grow from segment to segment through the record (an unstable
    loop; `growth`);
  - ``damping``: the linear closed loop's least-damped pole pair has a damping ratio of at least
    `MIN_ZETA` (``overtuned`` and ``level_pi`` are meant to ring and are exempt);
  - ``pv_follows``: the loop holds PV at its setpoint on average: ``|mean(PV - SP)|`` at most
    `MAX_PV_OFFSET` times the standard deviation of PV - SP (a PV that drifts away while OP
    works shows a process that does not respond to the valve);
  - ``pv_span``: PV finite and inside the transmitter's span, as in the original definition;
  - ``identifiable`` (sticky only): the friction element slips at least `MIN_SLIPS` times (moves
    of at least `MIN_MOVE_OVER_S` x ``S``), is stuck on at least `MIN_STUCK_FRACTION` of the
    samples, and its band ``S`` is at least `MIN_S_OVER_OP_NOISE` times OP's own noise: otherwise
    the valve moves on every sample, or hardly ever, and the record cannot show stiction.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DEFINITIONS", "robust_sd", "op_noise", "slips_and_stuck", "growth", "motion_starts", "inside_span",
           "check"]

DEFINITIONS = ("original", "identifiable")

MAX_SATURATED = 0.002
MAX_OP_RANGE_PCT = 80.0
MAX_OP_NOISE_PCT = 3.0
MIN_ZETA = 0.15
MAX_PV_OFFSET = 0.5
MIN_SLIPS = 6
MIN_MOVE_OVER_S = 0.25
MIN_STUCK_FRACTION = 0.10
MIN_S_OVER_OP_NOISE = 2.0
# a friction element that moves less than this between samples (% of span) is at rest
REST_PCT = 1e-6
# growth: the swing is compared over this many equal segments of the record
GROWTH_SEGMENTS = 8
GROWTH_MIN_RISES = 6
GROWTH_MIN_RATIO = 2.5
# scenarios whose point is a lightly damped loop
RINGING = ("overtuned", "level_pi")


def robust_sd(x: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (1.4826 MAD): blind to jumps."""
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def op_noise(op: np.ndarray) -> float:
    """OP's own sample-to-sample noise, % of span: robust sd of its first differences / sqrt 2."""
    return robust_sd(np.diff(np.asarray(op, dtype=float))) / math.sqrt(2.0)


def slips_and_stuck(y: np.ndarray, S_pct: float = 0.0, rest: float = REST_PCT) -> tuple[int, float]:
    """Separate moves of a friction element and the fraction of samples it is at rest.

    A move (slip) is a run of samples over which ``y`` changes by more than ``rest`` between
    samples; runs separated by at least one sample at rest count apart. A move counts only when
    the element travels at least `MIN_MOVE_OVER_S` x ``S_pct`` over it (max - min): a deadband
    valve nudged just past its band by noise moves, but by too little to show.
    """
    y = np.asarray(y, dtype=float)
    moving = np.abs(np.diff(y)) > rest
    if moving.size == 0:
        return 0, 1.0
    edges = np.diff(np.concatenate(([0], moving.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)          # first moving step of a run: y[s] -> y[s + 1]
    ends = np.flatnonzero(edges == -1)           # one past its last moving step
    need = MIN_MOVE_OVER_S * S_pct
    moves = 0
    for a, b in zip(starts, ends):
        seg = y[a:b + 1]
        if seg.max() - seg.min() >= need:
            moves += 1
    return moves, float(1.0 - moving.mean())


def growth(op: np.ndarray, segments: int = GROWTH_SEGMENTS) -> tuple[float, int]:
    """How OP's swing grows through the record.

    The swing of a segment is its 5-95 % range. Returns the mean swing of the last two segments
    over that of the first two, and how many segments swing more than 5 % wider than the one
    before: a limit cycle or a setpoint step rises once or twice, an unstable loop every time.
    """
    parts = np.array_split(np.asarray(op, dtype=float), segments)
    a = np.array([np.percentile(p, 95) - np.percentile(p, 5) if p.size else 0.0 for p in parts])
    ratio = float(a[-2:].mean() / max(a[:2].mean(), 1e-9))
    rises = int(np.count_nonzero(a[1:] > 1.05 * a[:-1]))
    return ratio, rises


def inside_span(pv: np.ndarray, span: float) -> bool:
    """PV stays within the transmitter's range (2 % margin) for 99 % of the record."""
    return float(np.mean((pv < -0.02 * span) | (pv > 1.02 * span))) <= 0.01


def check(definition: str, *, kind: str, sticky: bool, raw: dict, op: np.ndarray, pv: np.ndarray,
          span: float, meta: dict) -> list[str]:
    """Names of the guards a record fails (empty: it passes). Measurements are written to ``meta``.

    Parameters
    ----------
    definition : {"original", "identifiable"}
    kind, sticky : the record's scenario and label.
    raw : dict
        The closed loop's signals (`loop.run_loop`): ``op``, ``pv``, ``sp``, ``mv``, ``friction``.
    op, pv : ndarray
        OP and PV as the historian exports them.
    span : float
        The PV transmitter's span, PV units.
    meta : dict
        The record's drawn parameters; needs ``S_pct`` and ``closed_loop_zeta``.
    """
    sat = float(np.mean((raw["op"] <= 0.01) | (raw["op"] >= 99.99)))
    moves = motion_starts(raw["mv"])
    meta["op_saturated_fraction"] = sat
    meta["stem_moves"] = moves
    meta["pv_std"] = float(np.std(raw["pv"]))
    meta["op_std"] = float(np.std(raw["op"]))
    span_ok = bool(np.all(np.isfinite(raw["pv"]))) and inside_span(raw["pv"], span)
    if definition == "original":
        ok = sat <= 0.05 and (not sticky or moves >= 3) and span_ok
        return [] if ok else ["original"]
    failed = []
    if sat > MAX_SATURATED:
        failed.append("saturation")
    rng = float(np.percentile(raw["op"], 99) - np.percentile(raw["op"], 1))
    meta["op_range_pct"] = rng
    if rng > MAX_OP_RANGE_PCT:
        failed.append("op_range")
    noise = op_noise(op)
    meta["op_noise_pct"] = noise
    if noise > MAX_OP_NOISE_PCT:
        failed.append("op_noise")
    ratio, rises = growth(raw["op"])
    meta["op_growth"], meta["op_growth_rises"] = ratio, rises
    if rises >= GROWTH_MIN_RISES and ratio >= GROWTH_MIN_RATIO:
        failed.append("growing")
    if kind not in RINGING and not meta["closed_loop_zeta"] >= MIN_ZETA:
        failed.append("damping")
    e = pv - raw["sp"]
    offset = float(abs(np.mean(e)) / max(float(np.std(e)), 1e-12))
    meta["pv_offset_over_std"] = offset
    if offset > MAX_PV_OFFSET:
        failed.append("pv_follows")
    if not span_ok:
        failed.append("pv_span")
    if sticky:
        slips, stuck = slips_and_stuck(raw["friction"], meta["S_pct"])
        s_ratio = float(meta["S_pct"] / max(noise, 1e-12))
        meta["slips"], meta["stuck_fraction"] = slips, stuck
        meta["S_over_op_noise"] = s_ratio
        if slips < MIN_SLIPS or stuck < MIN_STUCK_FRACTION or s_ratio < MIN_S_OVER_OP_NOISE:
            failed.append("identifiable")
    return failed


def motion_starts(mv: np.ndarray, eps: float = 0.02) -> int:
    """Starts of stem motion: samples where the stem moves after a sample at rest."""
    moving = np.abs(np.diff(mv)) > eps
    return int(np.count_nonzero(moving[1:] & ~moving[:-1]) + (1 if moving.size and moving[0] else 0))
