"""Timestamps and the uniform time grid.

* `parse_times` turns a column of timestamp strings into seconds (UTC epoch for calendar times,
  plain seconds for numeric ``t`` columns). It recognises ISO 8601 and the common vendor formats
  (PI ``27-Nov-2024 23:59:00``, US ``11/27/2024 11:59:00 PM``, European ``27.11.2024 23:59``,
  ``2024/11/27 23:59:00``, compact ``20241127 235900``, epoch seconds/milliseconds). The format is
  chosen once from the column (day-first vs month-first decided by any field above 12) and then
  applied to every row.
* Naive calendar times are local times in ``tz`` (an IANA name; default UTC). The DST policy for
  the repeated autumn hour and the missing spring hour is ``dst``:

  - ``"infer"`` (default): in the repeated hour the first pass is read as summer time and, once the
    wall clock steps back, the second pass as winter time (in file order, newest-first files
    too); a time in the missing hour is shifted forward by the DST offset.
  - ``"earliest"`` / ``"latest"``: always the first / second reading of an ambiguous time.
  - ``"raise"``: an ambiguous or missing local time is an error naming the line.

* `to_grid` puts irregular, reversed or duplicated samples on a uniform grid: linear interpolation
  only inside gaps up to ``max_gap_s``; longer gaps stay NaN so that the caller splits the record.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Sequence

import numpy as np

from diagnose.errors import ConnectorError

DST_POLICIES = ("infer", "earliest", "latest", "raise")
_SECONDS_NAMES = {"t", "ts", "t_s", "time_s", "seconds", "sec", "s", "elapsed", "elapsed_s"}
_EPOCH = datetime(1970, 1, 1)

# (regex that a sample must match, strptime formats to try, day-first flag or None)
_VENDOR_FORMATS: list[tuple[str, list[str]]] = [
    (r"^\d{1,2}-[A-Za-z]{3}-\d{2,4}[ T]", ["%d-%b-%Y %H:%M:%S.%f", "%d-%b-%Y %H:%M:%S", "%d-%b-%Y %H:%M",
                                         "%d-%b-%y %H:%M:%S.%f", "%d-%b-%y %H:%M:%S", "%d-%b-%y %H:%M"]),
    (r"^\d{4}/\d{1,2}/\d{1,2}", ["%Y/%m/%d %H:%M:%S.%f", "%Y/%m/%d %H:%M:%S", "%Y/%m/%d %H:%M",
                                 "%Y/%m/%d"]),
    (r"^\d{8}[ T]?\d{4,6}", ["%Y%m%d %H%M%S", "%Y%m%dT%H%M%S", "%Y%m%d%H%M%S", "%Y%m%d %H%M"]),
]
_SLASH = re.compile(r"^(\d{1,2})[/.](\d{1,2})[/.](\d{2,4})")
_TIME_PARTS = ["%H:%M:%S.%f", "%H:%M:%S", "%H:%M", "%I:%M:%S %p", "%I:%M:%S.%f %p", "%I:%M %p"]


@dataclass(frozen=True)
class ParsedTimes:
    """Seconds per row (NaN where a cell was blank) and how they were read."""

    seconds: np.ndarray
    absolute: bool
    fmt: str
    tz: str | None


def _fail(msg: str, label: str | None, line: int | None, column: str | None) -> ConnectorError:
    return ConnectorError(msg, path=label, line=line, column=column)


def _numeric_times(texts: Sequence[str]) -> np.ndarray | None:
    try:
        arr = np.array([t if t else "nan" for t in texts], dtype=float)
    except ValueError:
        return None
    return arr


def _choose_format(samples: list[str]) -> str:
    """The strptime format (or ``"iso"``) that reads every sample."""
    first = samples[0]
    try:
        datetime.fromisoformat(first)
        return "iso"
    except ValueError:
        pass
    candidates: list[str] = []
    for pattern, fmts in _VENDOR_FORMATS:
        if re.match(pattern, first):
            candidates.extend(fmts)
    m = _SLASH.match(first)
    if m:
        sep = first[m.end(1)]
        yfmt = "%Y" if len(m.group(3)) == 4 else "%y"
        dayfirst = sep == "."
        monthfirst = False
        for s in samples:
            mm = _SLASH.match(s)
            if mm:
                if int(mm.group(1)) > 12:
                    dayfirst = True
                if int(mm.group(2)) > 12:
                    monthfirst = True
        orders = ["%m{0}%d{0}" + yfmt, "%d{0}%m{0}" + yfmt]
        if dayfirst and not monthfirst:
            orders.reverse()
        for date_fmt in orders:
            date_fmt = date_fmt.format(sep)
            candidates.extend(f"{date_fmt} {tp}" for tp in _TIME_PARTS)
            candidates.append(date_fmt)
    for fmt in candidates:
        try:
            for s in samples:
                datetime.strptime(s, fmt)
            return fmt
        except ValueError:
            continue
    raise ValueError(first)


def _tzinfo(tz: str | None):
    if tz is None or tz.upper() in ("UTC", "Z"):
        return timezone.utc
    m = re.fullmatch(r"(?:UTC)?([+-])(\d{1,2}):?(\d{2})?", tz.strip())
    if m:
        off = timedelta(hours=int(m.group(2)), minutes=int(m.group(3) or 0))
        return timezone(off if m.group(1) == "+" else -off)
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        return ZoneInfo(tz)
    except (ZoneInfoNotFoundError, ValueError):
        raise ConnectorError(f"unknown time zone {tz!r}; use an IANA name such as 'Europe/Berlin' "
                             f"or an offset such as '+01:00'") from None


def parse_times(texts: Sequence[str], *, tz: str | None = None, dst: str = "infer",
                label: str | None = None, column: str | None = None,
                lines: Sequence[int] | None = None) -> ParsedTimes:
    """Read a column of timestamps.

    Parameters
    ----------
    texts : sequence of str
        One cell per row (blank cells give NaN).
    tz : str, optional
        Time zone of naive calendar times (IANA name or ``+hh:mm``); default UTC.
    dst : {"infer", "earliest", "latest", "raise"}
        Policy for ambiguous / missing local times (see the module docstring).
    label, column, lines
        File name, column name and the file line of each row, for error messages.

    Returns
    -------
    ParsedTimes
        ``seconds`` is UTC epoch seconds when ``absolute`` else plain seconds.
    """
    if dst not in DST_POLICIES:
        raise ConnectorError(f"dst policy must be one of {', '.join(DST_POLICIES)}, not {dst!r}")
    n = len(texts)
    texts = [t.strip() for t in texts]
    line_of = (lambda k: lines[k]) if lines is not None else (lambda k: None)
    num = _numeric_times(texts)
    if num is not None:
        fin = num[np.isfinite(num)]
        if fin.size and np.all(np.abs(fin) > 1e11) and np.all(np.abs(fin) < 1e14):
            return ParsedTimes(num / 1000.0, True, "epoch_ms", "UTC")
        if fin.size and np.all(fin > 9e8) and np.all(fin < 5e9) and np.all(fin == np.round(fin)):
            return ParsedTimes(num, True, "epoch_s", "UTC")
        name = (column or "").strip().lower()
        if (fin.size > 1 and np.all(fin > 20000) and np.all(fin < 80000) and name not in _SECONDS_NAMES
                and np.median(np.abs(np.diff(fin))) < 1.0):
            # Excel serial days (1899-12-30 epoch), naive local time: read via calendar strings
            base = datetime(1899, 12, 30)
            iso = ["" if not np.isfinite(v) else (base + timedelta(days=float(v))).isoformat(timespec="milliseconds")
                   for v in num]
            pt = parse_times(iso, tz=tz, dst=dst, label=label, column=column, lines=lines)
            return ParsedTimes(pt.seconds, True, "excel_serial", pt.tz)
        return ParsedTimes(num, False, "seconds", None)
    nonblank = [k for k, t in enumerate(texts) if t]
    if not nonblank:
        raise _fail("timestamp column is empty", label, None, column)
    norm = [t.replace("Z", "+00:00") if t.endswith("Z") else t for t in texts]
    norm = [re.sub(r"(\d{2}:\d{2}:\d{2}),(\d+)", r"\1.\2", t) if "," in t else t for t in norm]
    sample_idx = nonblank[:: max(1, len(nonblank) // 200)][:200]
    try:
        fmt = _choose_format([norm[k] for k in sample_idx])
    except ValueError as exc:
        k = next(k for k in sample_idx if norm[k] == str(exc)) if str(exc) in norm else sample_idx[0]
        raise _fail(f"cannot read timestamp {texts[k][:40]!r}: not ISO 8601 or a known vendor format; "
                    "give the time as ISO 8601 (2024-11-27 23:59:00)", label, line_of(k), column) from None
    zone = _tzinfo(tz)
    if fmt == "iso":
        fast = _iso_fast(texts, nonblank, zone)
        if fast is not None:
            return ParsedTimes(fast, True, fmt, tz or "UTC")
    dts: list[datetime | None] = [None] * n
    parse = datetime.fromisoformat if fmt == "iso" else (lambda s, f=fmt: datetime.strptime(s, f))
    for k in nonblank:
        try:
            dts[k] = parse(norm[k])
        except ValueError:
            raise _fail(f"cannot read timestamp {texts[k][:40]!r} (other rows are {fmt!r})",
                        label, line_of(k), column) from None
    out = np.full(n, np.nan)
    aware = [dts[k].tzinfo is not None for k in nonblank]  # type: ignore[union-attr]
    if any(aware) and not all(aware):
        k = nonblank[aware.index(not aware[0])]
        raise _fail("timestamps mix times with and without a UTC offset", label, line_of(k), column)
    if aware[0]:
        for k in nonblank:
            out[k] = dts[k].timestamp()  # type: ignore[union-attr]
        return ParsedTimes(out, True, fmt, "offset")
    if zone is timezone.utc or isinstance(zone, timezone):
        off = zone.utcoffset(None).total_seconds()
        for k in nonblank:
            out[k] = (dts[k] - _EPOCH).total_seconds() - off  # type: ignore[operator]
        return ParsedTimes(out, True, fmt, tz or "UTC")
    _localise(dts, nonblank, zone, dst, out, label, column, line_of)
    return ParsedTimes(out, True, fmt, tz)


_TZ_SUFFIX_ML = re.compile(r"[+-]\d{2}:?\d{2}$", re.M)
_ISO_SHAPE = re.compile(r"^\d{4}-\d{2}-\d{2}([T ]\d{2}:\d{2}(:\d{2}(\.\d{1,6})?)?)?$")


def _iso_fast(texts: list[str], nonblank: list[int], zone) -> np.ndarray | None:
    """Vectorised ISO 8601 for the common cases: all naive (UTC or a fixed offset) or all ``Z``."""
    if not isinstance(zone, timezone):
        return None
    joined = "\n".join(texts[k] for k in nonblank)
    n_z = joined.count("Z")
    all_z = n_z == len(nonblank) and all(texts[k].endswith("Z") for k in nonblank) if n_z else False
    if n_z and not all_z:
        return None
    if not all_z and _TZ_SUFFIX_ML.search(joined):
        return None
    cells = [t[:-1] if all_z and t else t for t in texts]
    step = max(1, len(nonblank) // 50)
    if not all(_ISO_SHAPE.match(cells[k]) for k in nonblank[::step] + [nonblank[-1]]):
        return None
    try:
        arr = np.array([c if c else "NaT" for c in cells], dtype="datetime64[us]")
    except ValueError:
        return None
    sec = arr.astype("int64").astype(float) / 1e6
    sec[np.isnat(arr)] = np.nan
    if not all_z:
        sec -= zone.utcoffset(None).total_seconds()
    return sec


def _localise(dts, nonblank, zone, dst, out, label, column, line_of) -> None:
    """Naive local times -> UTC seconds under the DST policy (in place into ``out``)."""
    first = [dts[k].replace(tzinfo=zone, fold=0).timestamp() for k in nonblank]
    second = [dts[k].replace(tzinfo=zone, fold=1).timestamp() for k in nonblank]
    walls = [(dts[k] - _EPOCH).total_seconds() for k in nonblank]
    descending = len(walls) > 1 and walls[-1] < walls[0]
    order = range(len(nonblank) - 1, -1, -1) if descending else range(len(nonblank))
    in_second_pass = False
    last_wall = None
    for i in order:
        k = nonblank[i]
        a, b = first[i], second[i]
        if a == b:
            out[k] = a
            in_second_pass = False
            last_wall = None
            continue
        exists = datetime.fromtimestamp(a, zone).replace(tzinfo=None) == dts[k]
        if not exists:  # spring-forward hole: shift forward by the offset change
            if dst == "raise":
                raise ConnectorError(f"local time {dts[k]} does not exist in {zone} (DST change); "
                                     "choose --dst earliest/latest or give UTC times",
                                     path=label, line=line_of(k), column=column)
            out[k] = max(a, b)
            continue
        if dst == "raise":
            raise ConnectorError(f"local time {dts[k]} is ambiguous in {zone} (DST change); "
                                 "choose --dst earliest/latest/infer or give UTC times",
                                 path=label, line=line_of(k), column=column)
        if dst == "earliest":
            out[k] = min(a, b)
        elif dst == "latest":
            out[k] = max(a, b)
        else:
            if last_wall is not None and walls[i] < last_wall:
                in_second_pass = True
            out[k] = max(a, b) if in_second_pass else min(a, b)
            last_wall = walls[i]


def iso_utc(seconds: float) -> str:
    """UTC epoch seconds as ISO 8601 with ``Z``."""
    return datetime.fromtimestamp(seconds, tz=timezone.utc).isoformat().replace("+00:00", "Z")


# --------------------------------------------------------------------------------------------- grid

@dataclass(frozen=True)
class Cleaned:
    """One series after sorting and de-duplication."""

    t: np.ndarray
    x: np.ndarray
    n_duplicates: int
    reversed: bool


def clean_series(t: np.ndarray, x: np.ndarray) -> Cleaned:
    """Drop rows without a time, sort by time, keep the first of duplicated times."""
    keep = np.isfinite(t)
    t, x = t[keep], x[keep]
    reversed_ = bool(t.size > 1 and np.count_nonzero(np.diff(t) < 0) > 0.5 * (t.size - 1))
    if t.size > 1 and np.any(np.diff(t) <= 0):
        order = np.argsort(t, kind="stable")  # duplicates keep file order
        t, x = t[order], x[order]
        dup = np.concatenate([[False], np.diff(t) == 0])
        # a duplicated time keeps the first finite value given for it
        n_dup = int(np.count_nonzero(dup))
        if n_dup:
            grp = np.cumsum(~dup) - 1
            best = np.full(grp[-1] + 1, np.nan)
            fin = np.isfinite(x)
            # first finite value of each group
            idx = np.flatnonzero(fin)
            g = grp[idx]
            first_fin = np.unique(g, return_index=True)
            best[first_fin[0]] = x[idx[first_fin[1]]]
            t = t[~dup]
            x = best
    else:
        n_dup = 0
    return Cleaned(t, x, n_dup, reversed_)


def estimate_period(times: Sequence[np.ndarray]) -> float:
    """Median positive spacing over several sorted time vectors (seconds)."""
    d = [np.diff(t) for t in times if t.size > 1]
    d = [v[v > 0] for v in d]
    allv = np.concatenate(d) if d else np.empty(0)
    if allv.size == 0:
        return float("nan")
    return float(np.median(allv))


def irregularity(t: np.ndarray, ts_s: float, max_gap_s: float) -> float:
    """Fraction of sample intervals (gaps excluded) that differ from ``ts_s`` by more than 10 %."""
    d = np.diff(t)
    d = d[(d > 0) & (d <= max_gap_s)]
    if d.size == 0:
        return 0.0
    return float(np.count_nonzero(np.abs(d - ts_s) > 0.1 * ts_s) / d.size)


def to_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, int]:
    """Values of a sorted series on ``grid``: linear inside gaps up to ``max_gap_s``, NaN beyond.

    Returns the gridded values and how many grid points were filled by interpolation across a
    missing or bad sample.
    """
    ok = np.isfinite(x)
    tv, xv = t[ok], x[ok]
    out = np.full(grid.shape, np.nan)
    if tv.size == 0:
        return out, 0
    if tv.size == 1:
        hit = np.abs(grid - tv[0]) < 1e-6 * max(1.0, abs(tv[0])) + 1e-9
        out[hit] = xv[0]
        return out, 0
    j = np.searchsorted(tv, grid, side="right")
    inside = (j > 0) & (j < tv.size)
    jj = np.clip(j, 1, tv.size - 1)
    t0, t1 = tv[jj - 1], tv[jj]
    span = t1 - t0
    tol = 1e-6 * max(1.0, float(np.nanmax(np.abs(grid))) * 1e-6)
    exact_end = np.abs(grid - tv[-1]) <= 1e-9 + tol
    w = np.where(span > 0, (grid - t0) / np.where(span > 0, span, 1.0), 0.0)
    vals = xv[jj - 1] + w * (xv[jj] - xv[jj - 1])
    good = inside & (span <= max_gap_s * (1 + 1e-9))
    out[good] = vals[good]
    out[exact_end] = xv[-1]
    step = float(grid[1] - grid[0]) if grid.size > 1 else max_gap_s
    on_sample = (j > 0) & (np.abs(grid - t0) <= 1e-6 * step)
    out[on_sample] = xv[jj - 1][on_sample]   # a grid point on a sample keeps it, even beside a long gap
    # interpolation across a missing/bad sample: interval longer than 1.5 grid steps
    filled = int(np.count_nonzero(good & (span > 1.5 * step) & ~on_sample))
    return out, filled


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` index pairs of the True runs of a boolean array."""
    if mask.size == 0:
        return []
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), stops.tolist()))
