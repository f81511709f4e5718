"""Data-quality assessment of a loop record (pure: arrays in, findings out, no I/O).

`assess(record)` looks at the signals themselves and returns `diagnose.record.Finding`s:

``compression``
    Historian compression: long runs that are *exactly* straight (swinging door, interpolated
    back) or exactly flat with arbitrary jumps between them (box-car / deadband, stepped back), in
    OP or PV. Such records fake stiction shapes: the finding is a ``warning`` and the fitting stage
    must lower its confidence.
``quantisation``
    Values on a coarse grid (few distinct levels over the signal's range).
``op_saturation``
    OP at 0 % or 100 % of span for a noticeable share of the record.
``op_fraction``
    OP moves but stays within 0..1: logged as a fraction of span, not in %. Read as %, every valve
    movement looks a hundred times too small, so a sticky valve passes for a healthy one: a
    ``warning`` telling the user to scale OP to % or to pass the right column, in the words of
    where the record came from (``--op`` for a file, ``op=`` for a DataFrame or arrays).
``manual_mode``
    Samples in manual, from ``meta["manual_intervals"]`` set by a connector that read a mode column.
``frozen``
    A value that does not change for a long stretch (a sensor or link that froze); an OP that never
    moves at all is reported as ``frozen`` with ``data["whole_record"] = True`` (a ``warning``: the
    loop cannot show stiction, and the diagnosis says so).

Connector-level findings (``gap``, ``bad_values``, ``duplicates``, ``segment``,
``irregular_sampling``) come from the reader, which sees the raw file.

For tests and experiments the module also has the two classic compressors, `swinging_door` and
`boxcar`, and `decompress` to interpolate archived points back onto the sample grid.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .record import Finding, LoopRecord

# thresholds (documented in docs/connectors.md)
LINE_MIN_POINTS = 6           # a straight run has at least this many samples on one line
FLAT_MIN_POINTS = 5           # a flat run has at least this many equal samples
COMPRESSION_LINEAR_FRAC = 0.25  # share of samples on sloped straight runs that means compression
COMPRESSION_FLAT_FRAC = 0.60  # share on flat runs (not quantisation) that means box-car compression
FROZEN_FRAC = 0.25            # one flat run this long (share of the record) is a frozen value
FROZEN_MIN_POINTS = 30
SATURATION_FRAC = 0.05
QUANT_MAX_LEVELS = 50
#: OP within 0..1 that moves by at least this much (1 % of span if it is a fraction) is taken for a
#: fraction; an OP in % that never leaves 0..1 % (a valve all but shut for the whole record) is
#: flagged too, and the message says how to tell.
FRACTION_MIN_MOVE = 0.01
#: A fraction OP is scaled to % when OP x 100 lies within this many % of span of the recorded stem
#: position (median): a valve follows OP to within its band (S rarely exceeds 10 %).
FRACTION_MV_MAX_OFF_PCT = 10.0


def _tolerance(x: np.ndarray) -> float:
    """Largest spread of first differences that still counts as "exactly straight".

    Float32 storage (about 2**-23 relative) and decimal rounding of the export leave small residues
    on an interpolated straight line: rounded to a resolution r, the first differences of a
    straight line take at most two neighbouring values, r apart.
    """
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    tol = 4.0 * 2.0 ** -23 * scale + 1e-12
    res = decimal_resolution(x)
    if res is not None:
        tol = max(tol, res * (1 + 1e-6) + 1e-9 * scale)
    return tol


def decimal_resolution(x: np.ndarray) -> float | None:
    """10**-d for the fewest decimals d (<= 8) that write every value exactly, else None."""
    if x.size == 0:
        return None
    sample = x[:: max(1, x.size // 2000)]
    scale = max(1.0, float(np.max(np.abs(sample))))
    for d in range(0, 9):
        y = sample * 10.0 ** d
        if np.all(np.abs(y - np.round(y)) <= 1e-6 * max(1.0, scale * 10.0 ** d * 1e-9) + 1e-9 * scale * 10.0 ** d):
            return 10.0 ** -d
    return None


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def straight_and_flat(x: np.ndarray) -> dict[str, Any]:
    """Shares of samples on exactly straight sloped runs and on exactly flat runs."""
    n = x.size
    out = {"linear_frac": 0.0, "flat_frac": 0.0, "n_linear_runs": 0, "longest_flat": 0,
           "longest_flat_start": 0, "tol": 0.0}
    if n < LINE_MIN_POINTS + 2:
        return out
    tol = _tolerance(x)
    out["tol"] = tol
    d1 = np.diff(x)
    d2 = np.abs(np.diff(d1))
    flat_step = np.abs(d1) <= tol * 0.25
    # flat runs: consecutive equal samples
    s, e = _runs(flat_step)
    lens = e - s + 1  # samples
    keep = lens >= FLAT_MIN_POINTS
    flat_cover = np.zeros(n, bool)
    for a, b in zip(s[keep], e[keep]):
        flat_cover[a:b + 1] = True
    if np.any(keep):
        k = int(np.argmax(lens))
        out["longest_flat"] = int(lens[k])
        out["longest_flat_start"] = int(s[k])
    # straight runs: every window of LINE_MIN_POINTS samples whose first differences spread by at
    # most tol, with a non-zero slope
    w = LINE_MIN_POINTS - 1
    lin_cover = np.zeros(n, bool)
    n_runs = 0
    if d1.size >= w:
        win = np.lib.stride_tricks.sliding_window_view(d1, w)
        straight = (np.ptp(win, axis=1) <= tol) & (np.abs(win.mean(axis=1)) > tol * 0.25)
        s, e = _runs(straight)
        n_runs = int(s.size)
        for a, b in zip(s, e):
            lin_cover[a:b - 1 + w + 1] = True
    out["linear_frac"] = float(np.count_nonzero(lin_cover & ~flat_cover)) / n
    out["flat_frac"] = float(np.count_nonzero(flat_cover)) / n
    out["n_linear_runs"] = n_runs
    return out


def quantum(x: np.ndarray) -> dict[str, Any] | None:
    """The value grid of a quantised signal: step size, levels over the range, or None."""
    d = np.abs(np.diff(x))
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    d = d[d > 4.0 * 2.0 ** -23 * scale + 1e-12]
    if d.size < 10:
        return None
    q = float(np.min(d))
    r = d / q
    on_grid = np.abs(r - np.round(r)) <= 0.02
    if np.count_nonzero(on_grid) < 0.95 * d.size:
        return None
    span = float(np.percentile(x, 99) - np.percentile(x, 1))
    levels = span / q if q > 0 else np.inf
    return {"step": q, "levels": float(levels), "single_step_frac": float(np.mean(np.round(r) == 1))}


def _compression(role: str, x: np.ndarray) -> Finding | None:
    sf = straight_and_flat(x)
    lin, flat = sf["linear_frac"], sf["flat_frac"]
    kind = None
    if lin >= COMPRESSION_LINEAR_FRAC and (sf["n_linear_runs"] >= 3 or lin >= 0.5):
        kind = "swinging-door (straight runs)"
    elif flat >= COMPRESSION_FLAT_FRAC and sf["longest_flat"] < FROZEN_FRAC * x.size:
        q = quantum(x)
        if q is None:
            kind = "box-car (flat runs with jumps)"
    if kind is None:
        return None
    return Finding(
        "compression",
        f"{role.upper()} looks historian-compressed ({kind}: {100 * lin:.0f} % of samples on exactly "
        f"straight runs, {100 * flat:.0f} % on flat runs); interpolated compressed data can fake "
        "stiction shapes: export raw/sampled values with compression off if you can",
        "warning",
        {"role": role, "kind": kind.split()[0], "linear_frac": round(lin, 4), "flat_frac": round(flat, 4),
         "n_linear_runs": sf["n_linear_runs"]},
    )


def _frozen(role: str, x: np.ndarray, ts_s: float) -> Finding | None:
    n = x.size
    if n == 0:
        return None
    span = float(np.max(x) - np.min(x))
    if span <= 4.0 * 2.0 ** -23 * float(np.max(np.abs(x))) + 1e-12:
        return Finding("frozen", f"{role.upper()} never moves (constant {float(x[0]):.4g} over all {n} samples)"
                       + ("; a loop whose OP never moves cannot show stiction" if role == "op" else ""),
                       "warning", {"role": role, "whole_record": True, "value": float(x[0]), "samples": n})
    sf = straight_and_flat(x)
    L = sf["longest_flat"]
    if L >= max(FROZEN_MIN_POINTS, FROZEN_FRAC * n):
        return Finding("frozen", f"{role.upper()} stays exactly at {float(x[sf['longest_flat_start']]):.4g} "
                       f"for {L} samples ({L * ts_s:.0f} s, {100 * L / n:.0f} % of the record): a frozen "
                       "sensor, link or historian value?", "warning",
                       {"role": role, "whole_record": False, "start": sf["longest_flat_start"], "samples": L})
    return None


def _quantisation(role: str, x: np.ndarray) -> Finding | None:
    q = quantum(x)
    if q is None or not np.isfinite(q["levels"]) or q["levels"] > QUANT_MAX_LEVELS:
        return None
    sev = "warning" if q["levels"] < 20 else "info"
    return Finding("quantisation", f"{role.upper()} is quantised in steps of {q['step']:.4g} "
                   f"({q['levels']:.0f} levels over its range); small valve moves may be hidden", sev,
                   {"role": role, "step": q["step"], "levels": round(q["levels"], 1)})


def op_saturation(op: np.ndarray) -> Finding | None:
    # at a limit = at 0 % (100 %) and exactly at the record's own minimum (maximum): clamped
    mn, mx = float(np.min(op)), float(np.max(op))
    eps = 1e-6 * max(1.0, abs(mn), abs(mx))
    lo = float(np.mean((op <= 0.5) & (op <= mn + eps))) if mn >= -0.5 else 0.0
    hi = float(np.mean((op >= 99.5) & (op >= mx - eps))) if mx <= 100.5 else 0.0
    frac = lo + hi
    if frac < 0.01:
        return None
    sev = "warning" if frac >= SATURATION_FRAC else "info"
    where = "0 %" if lo >= hi else "100 %"
    return Finding("op_saturation", f"OP is saturated (at 0 % or 100 % of span) for {100 * frac:.1f} % of the "
                   f"record, mostly at {where}; the valve cannot move there", sev,
                   {"frac_low": round(lo, 4), "frac_high": round(hi, 4)})


#: ``meta["format"]`` of a record read from a file (the layouts of `connectors.layouts`): its user
#: gives options as command-line flags.
FILE_FORMATS = ("wide", "long", "ragged", "influx", "dcs")


def op_scale_advice(record: LoopRecord) -> str:
    """How whoever made ``record`` gives OP in % of span: a tag map for a file (its ``range``
    scales OP, and the export stays as it is), a keyword for a DataFrame or arrays (Python, where
    there is no ``--op``), the register map for a Modbus device."""
    meta = record.meta or {}
    fmt = meta.get("format")
    if fmt in FILE_FORMATS:
        cols = meta.get("columns") or {}
        op, pv = cols.get("op") or "OP_TAG", cols.get("pv") or "PV_TAG"
        return (f'read OP as % of span with a tag map (--tags MAP.toml) holding [loops.{record.name}] with '
                f'op = {{ tag = "{op}", range = [0, 1] }} and pv = "{pv}", or pass the right column with --op')
    if fmt == "dataframe":
        return "scale OP's column to % (multiply by 100) or name the right column with op='COLUMN'"
    if fmt == "modbus":
        return "scale OP to % with range = [0, 1] on its register in the monitor's configuration"
    return "scale OP to % (multiply by 100) before passing it as op="


def _op_fraction(record: LoopRecord) -> Finding | None:
    op = record.op
    lo, hi = float(np.min(op)), float(np.max(op))
    if lo < 0.0 or hi > 1.0 or hi - lo < FRACTION_MIN_MOVE:
        return None
    return Finding("op_fraction", f"OP stays within 0..1 ({lo:.3g} to {hi:.3g}): it looks logged as a fraction "
                   "of span, not in %, so S, J and OP's travel are given in fractions of span (0.03 is 3 %) "
                   f"and the result is less certain; {op_scale_advice(record)}", "warning", {"min": lo, "max": hi})


def fraction_op_tracks_mv(op: np.ndarray, mv: np.ndarray) -> bool:
    """Does a fraction-of-span OP (``op_fraction``) scaled by 100 track a stem position in %?

    The stem position shows OP's scale: a valve follows OP to within its band, so OP x 100 lies
    within a few % of MV, while OP read as % lies some 50 % of span away. A fraction OP beside an MV
    that is itself within 0..1 (both fractions, or a valve all but shut in %) says nothing of the
    scale, and neither does an MV that OP x 100 does not follow."""
    op = np.asarray(op, dtype=float)
    mv = np.asarray(mv, dtype=float)
    if op.shape != mv.shape or float(np.max(mv)) <= 1.0 or float(np.min(mv)) < -1.0 or float(np.max(mv)) > 101.0:
        return False
    off_pct = float(np.median(np.abs(100.0 * op - mv)))
    off_raw = float(np.median(np.abs(op - mv)))
    return off_pct <= FRACTION_MV_MAX_OFF_PCT and off_pct < off_raw / 10.0


def rescaled_op_finding(f: Finding) -> Finding:
    """The ``op_fraction`` finding once OP was scaled to % by the stem position: information only."""
    return Finding("op_fraction", f"OP was logged as a fraction of span ({f.data.get('min', 0):.3g} to "
                   f"{f.data.get('max', 0):.3g}); the stem position (MV, in %) follows OP x 100, so OP was "
                   "multiplied by 100", "info", {**f.data, "rescaled": 100.0})


def findings_of(record: LoopRecord) -> tuple[Finding, ...]:
    """The record's findings, with `assess`'s added unless the reader already assessed it
    (``meta["quality_checked"]``)."""
    findings = tuple(record.findings)
    if not (record.meta or {}).get("quality_checked"):
        known = {(f.code, f.message) for f in findings}
        findings = findings + tuple(f for f in assess(record) if (f.code, f.message) not in known)
    return findings


def op_in_percent(record: LoopRecord, findings: tuple[Finding, ...]
                  ) -> tuple[LoopRecord, tuple[Finding, ...], str | None]:
    """OP logged as a fraction beside a stem position in %: the record with OP x 100, when MV shows
    that scale; the findings updated and the warning to give (None: the record as it was).

    Without MV the tool warns rather than guesses (OP 0..1 could be a valve all but shut); with MV
    the stem position is the scale. Fitted unscaled, OP -> MV needs a valve gain of 100 the valve fit
    does not have, so the fit finds no band and a sticky valve passes for a healthy one."""
    frac = next((f for f in findings if f.code == "op_fraction" and f.severity != "info"), None)
    if frac is None or record.mv is None or not fraction_op_tracks_mv(record.op, record.mv):
        return record, findings, None
    op = np.asarray(record.op, dtype=float) * 100.0
    info = rescaled_op_finding(frac)
    findings = tuple(info if f is frac else f for f in findings)
    sat = op_saturation(op)   # `assess` leaves it out for a fraction OP; in % it counts
    if sat is not None:
        findings += (sat,)
    rec_findings = tuple(info if f.code == "op_fraction" else f for f in record.findings)
    note = (f"OP stays within 0..1 ({frac.data.get('min', 0):.3g} to {frac.data.get('max', 0):.3g}) while the "
            "stem position (MV) is in % and follows OP x 100: OP was read as a fraction of span and "
            "multiplied by 100")
    ranges = dict(record.ranges or {})
    ranges.pop("op", None)
    return record.replace(op=op, findings=rec_findings, ranges=ranges), findings, note


def _manual(record: LoopRecord) -> Finding | None:
    iv = record.meta.get("manual_intervals") if record.meta else None
    if not iv:
        return None
    n_man = sum(int(b) - int(a) for a, b in iv)
    if n_man <= 0:
        return None
    frac = n_man / max(1, record.n)
    return Finding("manual_mode", f"the controller is in manual for {n_man} samples ({100 * frac:.1f} % of "
                   "the record); closed-loop shapes do not apply there", "warning",
                   {"samples": n_man, "frac": round(frac, 4), "intervals": [[int(a), int(b)] for a, b in iv][:50]})


def assess(record: LoopRecord) -> tuple[Finding, ...]:
    """Data-quality findings of a record from its signals (and ``meta["manual_intervals"]``)."""
    out: list[Finding] = []
    # a PV the reader found without a single usable value is a flat stand-in: nothing to assess
    pv_missing = any(f.code == "pv_missing" for f in record.findings)
    for role in ("op",) if pv_missing else ("op", "pv"):
        x = getattr(record, role)
        f = _frozen(role, x, record.ts_s)
        if f is not None:
            out.append(f)
            if f.data.get("whole_record"):
                continue
        for check in (_compression, _quantisation):
            f = check(role, x)
            if f is not None:
                out.append(f)
    f = _op_fraction(record)
    if f is not None:
        out.append(f)
    else:
        f = op_saturation(record.op)  # at 0 % or 100 %: meaningless for a fraction
        if f is not None:
            out.append(f)
    f = _manual(record)
    if f is not None:
        out.append(f)
    return tuple(out)


# ----------------------------------------------------------------------------------------- compressors

def swinging_door(t: np.ndarray, x: np.ndarray, dev: float) -> np.ndarray:
    """Indices of the points a swinging-door compressor with deviation ``dev`` archives.

    Like a historian's archive it stores actual values (the point before the one that closed the
    doors), so the linear interpolation between archived points can be up to ``2 * dev`` off a raw
    point (usually much less).
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    n = x.size
    if n <= 2:
        return np.arange(n)
    keep = [0]
    a = 0
    up, lo = np.inf, -np.inf
    for i in range(1, n):
        dt = t[i] - t[a]
        s_up = (x[i] + dev - x[a]) / dt
        s_lo = (x[i] - dev - x[a]) / dt
        nu, nl = min(up, s_up), max(lo, s_lo)
        if nl > nu:  # the doors opened past parallel: archive the previous point
            a = i - 1
            keep.append(a)
            dt = t[i] - t[a]
            up = (x[i] + dev - x[a]) / dt
            lo = (x[i] - dev - x[a]) / dt
        else:
            up, lo = nu, nl
    if keep[-1] != n - 1:
        keep.append(n - 1)
    return np.asarray(keep)


def boxcar(x: np.ndarray, dev: float) -> np.ndarray:
    """Indices a box-car (exception-deviation) filter archives: a point when it differs from the last
    archived value by more than ``dev``, together with the point before it."""
    x = np.asarray(x, float)
    n = x.size
    if n <= 2:
        return np.arange(n)
    keep = [0]
    last = x[0]
    for i in range(1, n):
        if abs(x[i] - last) > dev:
            if keep[-1] != i - 1:
                keep.append(i - 1)
            keep.append(i)
            last = x[i]
    if keep[-1] != n - 1:
        keep.append(n - 1)
    return np.asarray(keep)


def decompress(t: np.ndarray, x: np.ndarray, idx: np.ndarray, *, kind: str = "linear") -> np.ndarray:
    """Archived points ``idx`` back on the sample times ``t`` (``linear`` or ``step`` hold)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    if kind == "linear":
        return np.interp(t, t[idx], x[idx])
    j = np.searchsorted(t[idx], t, side="right") - 1
    return x[idx][np.clip(j, 0, idx.size - 1)]
