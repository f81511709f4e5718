"""Timestamps and the uniform time grid.

* `parse_times` turns a column of timestamps into seconds (UTC epoch for calendar times, plain
  seconds for numeric ``t`` columns). pandas (`pandas.to_datetime`) does the parsing; what is ours
  is which format a column is in: ISO 8601 or one of the vendor formats (PI
  ``27-Nov-2024 23:59:00``, US ``11/27/2024 11:59:00 PM``, European ``27.11.2024 23:59``,
  ``2024/11/27 23:59:00``, compact ``20241127 235900``), epoch seconds or milliseconds, Excel
  serial days. The format is chosen once from a sample of the column (day-first vs month-first
  decided by any field above 12, else by the closer dates, else by custom and reported as a
  guess; ``dayfirst`` overrides) and applied to every row.
* Naive calendar times are local times in ``tz`` (an IANA name; default UTC), localised with
  `pandas.Series.dt.tz_localize`. The DST policy for the repeated autumn hour and the missing
  spring hour is ``dst``:

  - ``"infer"`` (default): in the repeated hour the first pass is read as summer time and, once the
    wall clock steps back, the second pass as winter time (in file order, newest-first files
    too); a time in the missing hour is shifted forward by the DST offset.
  - ``"earliest"`` / ``"latest"``: always the first / second reading of an ambiguous time.
  - ``"raise"``: an ambiguous or missing local time is an error naming the line.

* `clean_series` sorts and de-duplicates a series (pandas ``groupby().first()``); `to_grid` puts it
  on a uniform grid with our gap policy: linear interpolation only inside gaps up to ``max_gap_s``;
  longer gaps stay NaN so that the caller splits the record.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd

from diagnose.errors import ConnectorError

from .columns import FRAME_LABEL

DST_POLICIES = ("infer", "earliest", "latest", "raise")
#: A series' last sample this fraction of a grid step off the last grid point still lands on it.
END_TOLERANCE = 1e-3
_SECONDS_NAMES = {"t", "ts", "t_s", "time_s", "seconds", "sec", "s", "elapsed", "elapsed_s"}
_EPOCH = datetime(1970, 1, 1)
_EXCEL_EPOCH_US = int((datetime(1899, 12, 30) - _EPOCH) / timedelta(microseconds=1))

# (regex that a sample must match, strptime formats to try)
_VENDOR_FORMATS: list[tuple[str, list[str]]] = [
    (r"^\d{1,2}-[A-Za-z]{3}-\d{2,4}[ T]", ["%d-%b-%Y %H:%M:%S.%f", "%d-%b-%Y %H:%M:%S", "%d-%b-%Y %H:%M",
                                         "%d-%b-%y %H:%M:%S.%f", "%d-%b-%y %H:%M:%S", "%d-%b-%y %H:%M"]),
    (r"^\d{4}/\d{1,2}/\d{1,2}", ["%Y/%m/%d %H:%M:%S.%f", "%Y/%m/%d %H:%M:%S", "%Y/%m/%d %H:%M",
                                 "%Y/%m/%d"]),
    (r"^\d{8}[ T]?\d{4,6}", ["%Y%m%d %H%M%S", "%Y%m%dT%H%M%S", "%Y%m%d%H%M%S", "%Y%m%d %H%M"]),
]
_SLASH = re.compile(r"^(\d{1,2})[/.-](\d{1,2})[/.-](\d{2,4})")
_TIME_PARTS = ["%H:%M:%S.%f", "%H:%M:%S", "%H:%M", "%I:%M:%S %p", "%I:%M:%S.%f %p", "%I:%M %p"]
# an ISO time with a UTC offset after it (a date alone ends in "-27" and is no offset)
_NAT = np.iinfo(np.int64).min
_OFFSET = re.compile(r"[T\s]\S*[+-]\d{2}(?::?\d{2}(?::?\d{2}(?:\.\d+)?)?)?$")
_FRACTION_COMMA = re.compile(r"(\d{2}:\d{2}:\d{2}),(\d+)")
# .NET writes seconds to 7 digits (``8:00:00.0000000 AM``); strptime's %f reads at most 6
_LONG_FRACTION = re.compile(r"(\d:\d{2}:\d{2}\.\d{6})\d+")


@dataclass(frozen=True)
class ParsedTimes:
    """Seconds per row (NaN where a cell was blank) and how they were read."""

    seconds: np.ndarray
    absolute: bool
    fmt: str
    tz: str | None
    #: When the dates read both day first and month first alike (every field 12 or less, the same
    #: span either way) and no ``dayfirst`` was given: how they were read (``read``: "month first"
    #: or "day first"), the first stamp (``example``) and its date as read (``date``). Else None.
    order_guessed: dict | None = None
    #: The distinct dates (``05/03/2026``) of the rows looked at when the format puts day and month
    #: in an order (``%d/%m`` or ``%m/%d``), else None: what `shared_date_order` pools over the
    #: files of one export.
    dates: tuple[str, ...] | None = None


def _fail(msg: str, label: str | None, line: int | None, column: str | None) -> ConnectorError:
    return ConnectorError(msg, path=label, line=line, column=column)


def _choose_format(samples: list[str], dayfirst: bool | None = None) -> tuple[str, bool]:
    """The strptime format (or ``"iso"``) that reads every sample, and whether its date order was a
    guess: the samples read alike day first and month first (``dayfirst`` given: never a guess;
    it is a preference, and dates that read only one way are read that way)."""
    first = samples[0]
    try:
        datetime.fromisoformat(first)
        return "iso", False
    except ValueError:
        pass
    guessed = False
    candidates: list[str] = []
    for pattern, fmts in _VENDOR_FORMATS:
        if re.match(pattern, first):
            candidates.extend(fmts)
    m = _SLASH.match(first)
    if m:
        sep = first[m.end(1)]
        yfmt = "%Y" if len(m.group(3)) == 4 else "%y"
        _, day_above_12, month_above_12 = _fields_above_12(samples)
        orders = [f"%m{sep}%d{sep}{yfmt}", f"%d{sep}%m{sep}{yfmt}"]
        if dayfirst is not None:
            if dayfirst:
                orders.reverse()
        elif day_above_12 and not month_above_12:
            orders.reverse()
        elif not month_above_12:
            # No field above 12 (an export of the 1st to the 12th of a month): the reading whose
            # dates lie closer together, not a calendar order: 01/03 .. 09/03 read month-first
            # spreads nine days over nine months. Equal spans keep the locale's custom: day
            # first after dots (German) and dashes (Dutch), month first after slashes (US).
            default = orders[1 if sep in ".-" else 0]
            spans = [_date_span(samples, f) for f in orders]
            orders.sort(key=lambda f: (_date_span(samples, f), f != default))
            # a guess the user must hear of (a one-day UK export reads as US), unless day and
            # month are equal in every date (either reading is the same) or the dates are
            # dotted: day first wherever dots are written
            guessed = (spans[0] == spans[1] and spans[0] != math.inf and sep != "."
                       and any(mm.group(1) != mm.group(2) for mm in map(_SLASH.match, samples) if mm))
        for date_fmt in orders:
            candidates.extend(f"{date_fmt} {tp}" for tp in _TIME_PARTS)
            candidates.append(date_fmt)
    for fmt in candidates:
        try:
            for s in samples:
                datetime.strptime(s, fmt)
            return fmt, guessed
        except ValueError:
            continue
    raise ValueError(first)


def _fields_above_12(dates: Iterable[str]) -> tuple[bool, bool, bool]:
    """(any day/month-style date, a first field above 12, a second field above 12) of the dates
    such as ``05/03/2026``: a field above 12 can only be a day."""
    seen = first = second = False
    for d in dates:
        m = _SLASH.match(d)
        if m:
            seen = True
            first = first or int(m.group(1)) > 12
            second = second or int(m.group(2)) > 12
    return seen, first, second


def alike_both_ways(dates: Iterable[str]) -> bool:
    """Whether every date has its day and its month at 12 or less: read alone, such dates cannot
    say which comes first (only how close together each reading puts them)."""
    seen, first, second = _fields_above_12(dates)
    return seen and not first and not second


def shared_date_order(dates: Iterable[str]) -> bool | None:
    """The date order that the dates of several files (one export, a file per day) say together:
    True day first, False month first, None when they cannot tell.

    A first field above 12 says day first and a second above 12 month first (both: the files are
    not one export, None). With every field 12 or less, the reading whose dates lie closer
    together (`_date_span`, as `parse_times` decides one column): a folder of one-day exports
    05/03/2026, 06/03/2026 ... is a week of March, not a week of months. Equal spans: None.
    """
    dates = [d for d in dates if _SLASH.match(d)]
    seen, first, second = _fields_above_12(dates)
    if not seen:
        return None
    if first or second:
        return None if first and second else first
    m = _SLASH.match(dates[0])
    sep, yfmt = dates[0][m.end(1)], "%Y" if len(m.group(3)) == 4 else "%y"
    month_first, day_first = (_date_span(dates, f) for f in (f"%m{sep}%d{sep}{yfmt}", f"%d{sep}%m{sep}{yfmt}"))
    if math.isinf(month_first) or math.isinf(day_first) or month_first == day_first:
        return None   # a date one reading cannot hold (no such day), or no difference
    return day_first < month_first


def _date_span(samples: list[str], date_fmt: str) -> float:
    """Days from the earliest to the latest date of the samples read with ``date_fmt`` (inf if one
    does not read)."""
    try:
        days = [datetime.strptime(m.group(0), date_fmt) for m in map(_SLASH.match, samples) if m]
    except ValueError:
        return math.inf
    return (max(days) - min(days)) / timedelta(days=1) if days else math.inf


def zone_of(tz: str | None):
    """The time zone a ``--tz`` option names: None or UTC, a fixed offset (``+01:00``) or an IANA
    name; an unknown name is a `ConnectorError` that says what to write instead."""
    if tz is None:
        return timezone.utc
    if not isinstance(tz, str):
        raise ConnectorError(f"time zone {tz!r} is not a zone name or an offset string; use an IANA name "
                             "such as 'Europe/Berlin' or an offset such as '+01:00'")
    if tz.strip().upper() in ("UTC", "Z"):
        return timezone.utc
    m = re.fullmatch(r"(?:UTC)?([+-])(\d{1,2}):?(\d{2})?", tz.strip())
    if m:
        hours, minutes = int(m.group(2)), int(m.group(3) or 0)
        if hours > 23 or minutes > 59:
            raise ConnectorError(f"time zone offset {tz!r} is out of range; offsets run from -23:59 to "
                                 "+23:59 with minutes below 60")
        off = timedelta(hours=hours, minutes=minutes)
        return timezone(off if m.group(1) == "+" else -off)
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        return ZoneInfo(tz)
    except (ZoneInfoNotFoundError, ValueError):
        raise ConnectorError(f"unknown time zone {tz!r}; use an IANA name such as 'Europe/Berlin' "
                             f"or an offset such as '+01:00'") from None


def _cells(col: Any) -> list[str]:
    """Stripped text of each cell ("" where empty)."""
    try:
        return [v.strip() for v in col]
    except AttributeError:
        return [v.strip() if isinstance(v, str) else "" if v is None or v != v else str(v).strip() for v in col]


def parse_times(texts: Any, *, tz: str | None = None, dst: str = "infer", label: str | None = None,
                column: str | None = None, lines: Sequence[int] | None = None,
                dayfirst: bool | None = None) -> ParsedTimes:
    """Read a column of timestamps.

    Parameters
    ----------
    texts : sequence of str, or a pandas Series (text or numbers)
        One cell per row (blank cells give NaN).
    tz : str, optional
        Time zone of naive calendar times (IANA name or ``+hh:mm``); default UTC.
    dst : {"infer", "earliest", "latest", "raise"}
        Policy for ambiguous / missing local times (see the module docstring).
    label, column, lines
        File name, column name and the file line of each row, for error messages.
    dayfirst : bool, optional
        Dates such as ``05/03/2026`` are day first (True) or month first (False). Default: decided
        from the column (`ParsedTimes.order_guessed` says when it could not be).

    Returns
    -------
    ParsedTimes
        ``seconds`` is UTC epoch seconds when ``absolute`` else plain seconds.
    """
    if dst not in DST_POLICIES:
        raise ConnectorError(f"dst policy must be one of {', '.join(DST_POLICIES)}, not {dst!r}")
    if dayfirst not in (None, True, False):
        raise ConnectorError(f"dayfirst must be True, False or None, not {dayfirst!r}")
    if isinstance(texts, pd.Series):
        texts = texts.to_numpy()
    if isinstance(texts, np.ndarray) and texts.dtype.kind in "fiu":
        return _numeric(np.array(texts, dtype=float), tz, dst, label, column, lines)

    def line_of(k: int) -> int | None:
        return int(lines[k]) if lines is not None else None

    cells = np.asarray(texts, dtype=object) if not isinstance(texts, np.ndarray) else texts.astype(object, copy=False)
    nonblank = np.flatnonzero(~pd.isna(cells))       # cells of white space only are found below
    if not nonblank.size:
        raise _fail("timestamp column is empty", label, None, column)
    if not all(isinstance(c, str) for c in cells[nonblank[:100]]):
        cells = np.array(_cells(cells), dtype=object)
        nonblank = nonblank[cells[nonblank] != ""]
        if not nonblank.size:
            raise _fail("timestamp column is empty", label, None, column)
    if _is_float(cells[nonblank[0]]):
        num = _float_cells(_cells(cells))
        if num is not None:
            return _numeric(num, tz, dst, label, column, lines)
    norm = cells
    if "," in "\x00".join(cells[nonblank]):       # 23:59:00,000: the fraction after a comma
        norm = np.array([_FRACTION_COMMA.sub(r"\1.\2", c.strip()) if isinstance(c, str) and "," in c else c
                         for c in cells], dtype=object)
    if _LONG_FRACTION.search(str(norm[nonblank[0]])):
        norm = np.array([_LONG_FRACTION.sub(r"\1", c) if isinstance(c, str) else c for c in norm], dtype=object)
    sample_idx = [k for k in nonblank[:: max(1, nonblank.size // 200)][:200] if norm[k].strip()]
    if not sample_idx:
        raise _fail("timestamp column is empty", label, None, column)
    samples = [_norm(norm[k]) for k in sample_idx]
    try:
        fmt, guessed = _choose_format(samples, dayfirst)
    except ValueError as exc:
        k = next((k for k, c in zip(sample_idx, samples) if c == str(exc)), sample_idx[0])
        raise _fail(f"cannot read timestamp {cells[k].strip()[:40]!r}: not ISO 8601 or a known vendor format; "
                    "give the time as ISO 8601 (2024-11-27 23:59:00)", label, line_of(k), column) from None
    zone = zone_of(tz)
    sub = norm[nonblank]
    us = np.full(len(norm), _NAT, dtype=np.int64)        # UTC (aware) or wall-clock (naive) µs
    aware = np.zeros(len(norm), bool)
    try:
        dt = pd.to_datetime(sub, format="ISO8601" if fmt == "iso" else fmt, errors="coerce")
    except (ValueError, OverflowError, TypeError):   # mixed UTC offsets, or with and without one
        aware[nonblank] = [bool(_OFFSET.search(c.strip())) for c in sub]
        for part, utc in ((aware, True), (~aware, False)):
            idx = nonblank[part[nonblank]]
            if idx.size:
                us[idx] = _to_us(norm[idx], fmt, utc)
    else:
        if dt.tz is not None:
            aware[nonblank] = True
            dt = dt.tz_convert("UTC").tz_localize(None)
        us[nonblank] = dt.as_unit("us").asi8
    bad = nonblank[us[nonblank] == _NAT]
    if bad.size:
        blank = _python_fallback(norm, bad, us, aware, fmt, cells, label, column, line_of)
        if blank.size:
            nonblank = np.setdiff1d(nonblank, blank)
            if not nonblank.size:
                raise _fail("timestamp column is empty", label, None, column)
    if aware[nonblank].any() and not aware[nonblank].all():
        first = aware[nonblank[0]]
        k = int(nonblank[np.flatnonzero(aware[nonblank] != first)[0]])
        raise _fail("timestamps mix times with and without a UTC offset", label, line_of(k), column)
    out = np.full(len(norm), np.nan)
    order = None
    if guessed:
        k = int(nonblank[0])
        order = {"read": "day first" if fmt.startswith("%d") else "month first", "example": str(cells[k]).strip(),
                 "date": (_EPOCH + timedelta(microseconds=int(us[k]))).date().isoformat()}
    dates = (tuple(sorted({m.group(0) for m in map(_SLASH.match, samples) if m}))
             if fmt.startswith(("%d", "%m")) else None)
    if aware[nonblank[0]]:
        out[nonblank] = us[nonblank] / 1e6
        return ParsedTimes(out, True, fmt, "offset", order, dates)
    out[nonblank] = localise(us, nonblank, zone, dst, label, column, line_of)
    return ParsedTimes(out, True, fmt, tz or "UTC", order, dates)


def _float_cells(cells: list[str]) -> np.ndarray | None:
    """Every non-empty cell as a float (NaN where empty), or None if one is not a number."""
    num = np.array(pd.to_numeric(np.array([c or "nan" for c in cells], dtype=object), errors="coerce"),
                   dtype=float)
    for k in np.flatnonzero(np.isnan(num)):
        if cells[k]:
            try:
                num[k] = float(cells[k])
            except (ValueError, OverflowError):
                return None
    return num


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except (ValueError, OverflowError):
        return False


def _numeric(num: np.ndarray, tz, dst, label, column, lines) -> ParsedTimes:
    """Epoch milliseconds or seconds, Excel serial days, or plain seconds."""
    fin = num[np.isfinite(num)]
    if fin.size and np.all(np.abs(fin) > 1e11) and np.all(np.abs(fin) < 1e14):
        return ParsedTimes(num / 1000.0, True, "epoch_ms", "UTC")
    if fin.size and np.all(fin > 9e8) and np.all(fin < 5e9) and np.all(fin == np.round(fin)):
        return ParsedTimes(num, True, "epoch_s", "UTC")
    name = (column or "").strip().lower()
    if (fin.size > 1 and np.all(fin > 20000) and np.all(fin < 80000) and name not in _SECONDS_NAMES
            and np.median(np.abs(np.diff(fin))) < 1.0):
        # Excel serial days (1899-12-30 epoch), naive local time, to the millisecond
        ok = np.flatnonzero(np.isfinite(num))
        wall = np.full(num.size, _NAT, dtype=np.int64)
        wall[ok] = _EXCEL_EPOCH_US + np.round(num[ok] * 86_400e3).astype(np.int64) * 1000
        out = np.full(num.size, np.nan)
        line_of = (lambda k: int(lines[k])) if lines is not None else (lambda k: None)
        out[ok] = localise(wall, ok, zone_of(tz), dst, label, column, line_of)
        return ParsedTimes(out, True, "excel_serial", tz or "UTC")
    return ParsedTimes(num, False, "seconds", None)


def _to_us(cells: np.ndarray, fmt: str, utc: bool) -> np.ndarray:
    """Microseconds since the epoch per cell (`_NAT` where pandas could not read it)."""
    try:
        dt = pd.to_datetime(cells, format="ISO8601" if fmt == "iso" else fmt, errors="coerce", utc=utc)
    except (ValueError, OverflowError, TypeError):
        return np.full(len(cells), _NAT, dtype=np.int64)
    if utc:
        dt = dt.tz_localize(None)
    return np.array(dt.as_unit("us").asi8)


def _norm(cell: str) -> str:
    """A cell as Python's parsers take it: stripped, ``Z`` as ``+00:00``."""
    cell = cell.strip()
    return cell.replace("Z", "+00:00") if cell.endswith("Z") else cell


def _python_fallback(norm, bad, us, aware, fmt, cells, label, column, line_of) -> np.ndarray:
    """Cells pandas did not read, by Python's own parser; the first that fails is an error.

    Returns the rows that were only white space (blank)."""
    blank = []
    for k in bad:
        s = _norm(norm[k])
        if not s:
            blank.append(k)
            continue
        try:
            dt = datetime.fromisoformat(s) if fmt == "iso" else datetime.strptime(s, fmt)
        except ValueError:
            raise _fail(f"cannot read timestamp {cells[k].strip()[:40]!r} (other rows are {fmt!r})",
                        label, line_of(k), column) from None
        aware[k] = dt.tzinfo is not None
        if aware[k]:
            us[k] = int((dt - datetime(1970, 1, 1, tzinfo=timezone.utc)) / timedelta(microseconds=1))
        else:
            us[k] = int((dt - _EPOCH) / timedelta(microseconds=1))
    return np.array(blank, dtype=np.int64)


def _policies(label: str | None, *names: str) -> str:
    """The DST policies ``names`` as the user gives them: ``--dst earliest/latest`` for a file,
    ``dst='earliest' or 'latest'`` for a DataFrame."""
    if label == FRAME_LABEL:
        quoted = [repr(n) for n in names]
        return "dst=" + ", ".join(quoted[:-1]) + " or " + quoted[-1]
    return "--dst " + "/".join(names)


def localise(wall_us: np.ndarray, rows: np.ndarray, zone, dst: str, label, column, line_of) -> np.ndarray:
    """UTC seconds of naive local times ``wall_us[rows]`` in ``zone`` under the DST policy."""
    wall = wall_us[rows]
    if isinstance(zone, timezone):
        return wall / 1e6 - zone.utcoffset(None).total_seconds()
    local = pd.DatetimeIndex(wall.astype("datetime64[us]"))
    utc = local.tz_localize(zone, ambiguous="NaT", nonexistent="NaT")
    sec = np.full(wall.size, np.nan)
    ok = ~utc.isna()
    sec[ok] = utc[ok].as_unit("us").asi8 / 1e6
    if ok.all():
        return sec
    # the repeated and the missing hour: our policy, in file order (reversed for newest-first files)
    # most steps decide, not the end points: a record within the repeated hour ends earlier than it starts
    descending = np.count_nonzero(np.diff(wall) < 0) > np.count_nonzero(np.diff(wall) > 0)
    order = np.arange(wall.size)[::-1] if descending else np.arange(wall.size)
    normal_seen = np.cumsum(ok[order])
    in_second_pass, last_wall, last_seen = False, None, None
    for i in np.flatnonzero(~ok[order]):
        k = int(order[i])
        if last_seen is not None and normal_seen[i] != last_seen:
            in_second_pass, last_wall = False, None      # an unambiguous time came between
        last_seen = normal_seen[i]
        dt = _EPOCH + timedelta(microseconds=int(wall[k]))
        a = dt.replace(tzinfo=zone, fold=0).timestamp()
        b = dt.replace(tzinfo=zone, fold=1).timestamp()
        if a == b:
            sec[k] = a
            continue
        line = line_of(int(rows[k]))
        if datetime.fromtimestamp(a, zone).replace(tzinfo=None) != dt:  # spring-forward hole
            if dst == "raise":
                raise ConnectorError(f"local time {dt} does not exist in {zone} (DST change); "
                                     f"choose {_policies(label, 'earliest', 'latest')} or give UTC times",
                                     path=label, line=line, column=column)
            sec[k] = max(a, b)
            continue
        if dst == "raise":
            raise ConnectorError(f"local time {dt} is ambiguous in {zone} (DST change); "
                                 f"choose {_policies(label, 'earliest', 'latest', 'infer')} or give UTC times",
                                 path=label, line=line, column=column)
        if dst == "earliest":
            sec[k] = min(a, b)
        elif dst == "latest":
            sec[k] = max(a, b)
        else:
            if last_wall is not None and wall[k] < last_wall:
                in_second_pass = True
            sec[k] = max(a, b) if in_second_pass else min(a, b)
            last_wall = wall[k]
    return sec


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
    n_shared: int = 0          # rows whose time stamp the row before or after has too, in file order
    clock_back_s: float | None = None   # the stamp after which the clock steps back about an hour


def clock_back(t: np.ndarray) -> float | None:
    """The stamp (seconds) after which the time stamps, in file order, step back by half an hour
    to an hour once and run on in order: local wall-clock time read without its zone, where daylight
    saving time ends (02:59:50 -> 02:00:00). None otherwise. Newest-first files mirror it.

    The stretch after the step must start within the stretch before it, as a repeated hour does: two
    pieces of an export pasted in the wrong order step back too, but repeat nothing."""
    t = t[np.isfinite(t)]
    if t.size < 3:
        return None
    d = np.diff(t)
    for sign in (1.0, -1.0):
        back = np.flatnonzero(sign * d < 0)
        if back.size == 1 and 1800.0 <= -sign * d[back[0]] <= 3600.0:
            k = int(back[0])
            if sign * t[k + 1] >= sign * t[0]:
                return float(t[k])
    return None


def spread_truncated(t: np.ndarray, ts_s: float) -> np.ndarray | None:
    """Times of rows whose stamps were truncated (``M/D/YYYY H:MM`` from a spreadsheet: six 10 s
    rows per minute), spread in file order at the period given, or None where that is not safe.

    Safe means: the stamps run one way in file order, every run of equal stamps but the first and
    last holds the same ``k >= 2`` rows, and consecutive stamps are whole multiples of ``k ts_s``
    apart, so each run fills its stamp's interval exactly. The first run, when short, is
    aligned to the end of its interval (truncation keeps a row in the interval it started).
    """
    if t.size < 3 or not np.all(np.isfinite(t)):
        return None
    d = np.diff(t)
    flip = bool(np.all(d <= 0)) and bool(np.any(d < 0))
    if flip:
        t = t[::-1]
    elif not np.all(d >= 0):
        return None
    starts = np.flatnonzero(np.concatenate(([True], np.diff(t) > 0)))
    lengths = np.diff(np.append(starts, t.size))
    if lengths.size < 3:
        return None
    k = int(lengths[1])
    step = k * ts_s
    jumps = np.diff(t[starts]) / step
    if (k < 2 or np.any(lengths[1:-1] != k) or lengths[0] > k or lengths[-1] > k
            or np.any(np.abs(jumps - np.rint(jumps)) > 1e-6) or np.any(np.rint(jumps) < 1)):
        return None
    pos = np.arange(t.size) - np.repeat(starts, lengths)
    pos[:lengths[0]] += k - lengths[0]
    out = t + pos * ts_s
    return out[::-1] if flip else out


def shared_rows(t: np.ndarray) -> int:
    """Rows whose time stamp the row before or after has too, in file order (rows without a time
    left out). Runs of equal stamps next to each other are the mark of truncation; a repeated hour
    (DST read as UTC) or overlapping exports duplicate stamps far apart in the file."""
    same = np.diff(t[np.isfinite(t)]) == 0
    return int(np.count_nonzero(np.concatenate(([False], same)) | np.concatenate((same, [False]))))


def clean_series(t: np.ndarray, x: np.ndarray) -> Cleaned:
    """Drop rows without a time, sort by time, keep the first finite value of duplicated times."""
    keep = np.isfinite(t)
    t, x = t[keep], x[keep]
    d = np.diff(t)
    reversed_ = bool(t.size > 1 and np.count_nonzero(d < 0) > 0.5 * (t.size - 1))
    if t.size > 1 and np.any(d <= 0):
        n_shared = shared_rows(t)
        back = clock_back(t)
        order = np.argsort(t, kind="stable")                     # duplicates keep file order
        t, x = t[order], x[order]
        if np.all(np.diff(t) > 0):
            return Cleaned(t, x, 0, reversed_, clock_back_s=back)
        s = pd.Series(x, index=t)
        first = s.groupby(level=0, sort=False).first()           # first non-NaN of each time
        return Cleaned(np.array(first.index, dtype=float), np.array(first, dtype=float),
                       len(s) - len(first), reversed_, n_shared, back)
    return Cleaned(t, x, 0, reversed_)


def estimate_period(times: Sequence[np.ndarray]) -> float:
    """Median positive spacing over several sorted time vectors (seconds), as the roundest number
    within the float resolution of the times (epoch seconds carry about 0.2 µs of noise: 100 ms
    data would otherwise give 0.09999990463256836 s)."""
    d = [np.diff(t) for t in times if t.size > 1]
    d = [v[v > 0] for v in d]
    allv = np.concatenate(d) if d else np.empty(0)
    if allv.size == 0:
        return float("nan")
    median = float(np.median(allv))
    return _roundest(median, 4 * max(float(np.spacing(np.max(np.abs(t[[0, -1]])))) for t in times if t.size > 1))


def _roundest(value: float, tol: float) -> float:
    """The number with the fewest significant digits within ``tol`` of ``value``."""
    for digits in range(1, 17):
        rounded = float(f"{value:.{digits}g}")
        if abs(rounded - value) <= tol:
            return rounded
    return value


@dataclass(frozen=True)
class Jitter:
    """A record stamped by a regular clock with jittered time stamps: sample ``k`` lies near
    ``offset + k ts_s``, within ``JITTER_SLOT`` of a period."""

    ts_s: float
    offset: float


#: Largest |time stamp - its slot| (in periods) for the slot model of `jittered_period` to hold.
JITTER_SLOT = 0.4


def jittered_period(times: Sequence[np.ndarray], median: float) -> Jitter | None:
    """The period of jittered sampling, or None where the median spacing stands.

    Stamps jittered by +-J around a regular clock give intervals spread over +-2J, and their median
    is a poor period (10 s data with +-3 s jitter: 10.069 s, 0.7 % off, which drifts a sample
    over the record and marks the drift as gaps). Where every time vector is irregular (more than
    5 % of intervals off the median by 2 %) yet each stamp sits within `JITTER_SLOT` of its slot
    on one regular clock, the fitted period is used, as the roundest number within two standard
    errors. The clock is found on the longest stretch without a gap (an interval over 2.5
    periods; slots from its mean spacing, then the clock fitted by least squares) and then fitted
    to every stamp, the gaps skipping whole slots: outages do not stop the clock. Two stamps in one
    slot, slots missing outside the gaps, or drift (clock-free random intervals) keep the median:
    regular and compressed exports are unchanged.
    """
    if not (np.isfinite(median) and median > 0):
        return None
    best: tuple[int, float, float, float] | None = None
    for t in times:
        d = np.diff(t)
        if t.size < 21 or np.any(d <= 0):
            return None
        gap = d > 2.5 * median
        inner = d[~gap]
        if np.count_nonzero(np.abs(inner - median) > 0.02 * median) <= 0.05 * inner.size:
            return None                                  # regular enough: the median is exact
        edges = np.concatenate(([0], np.flatnonzero(gap) + 1, [t.size]))
        i = int(np.argmax(np.diff(edges)))
        seg = t[edges[i]:edges[i + 1]]
        if seg.size < 21:
            return None
        fit = _clock(seg, float(seg[-1] - seg[0]) / (seg.size - 1), seg[0])
        if fit is None:
            return None
        # the whole vector on that clock: the gaps skip whole slots
        fit = _clock(t, fit[0], seg[0] + fit[1] - fit[0] * np.rint((seg[0] + fit[1] - t[0]) / fit[0]))
        if fit is None:
            return None
        slope, icpt, k, resid = fit
        skipped = int(np.sum(np.diff(k)[gap] - 1))
        if k[-1] - k[0] + 1 - skipped > 1.05 * t.size:
            return None                                  # slots missing outside the gaps: no clock
        se = float(np.std(resid) / np.sqrt(np.sum((k - k.mean()) ** 2)))
        if best is None or t.size > best[0]:
            best = (t.size, float(slope), float(t[0] + icpt), se)
    if best is None:
        return None
    _, slope, offset, se = best
    return Jitter(_roundest(slope, 2 * se), offset)


def _clock(t: np.ndarray, spacing: float, origin: float
           ) -> tuple[float, float, np.ndarray, np.ndarray] | None:
    """The regular clock through stamps ``t`` started from a guess (``spacing``, a slot at
    ``origin``): (period, offset from ``t[0]``, slot numbers, residuals), or None where two stamps
    share a slot or one sits further than `JITTER_SLOT` periods from its slot."""
    k = np.rint((t - origin) / spacing)
    for _ in range(2):                                   # a missing sample shifts the mean spacing
        slope, icpt = np.polyfit(k, t - t[0], 1)
        k = np.rint((t - t[0] - icpt) / slope)
    if np.any(np.diff(k) < 1):
        return None                                      # two stamps in one slot: no regular clock
    slope, icpt = np.polyfit(k, t - t[0], 1)
    resid = t - t[0] - (icpt + slope * k)
    if np.max(np.abs(resid)) > JITTER_SLOT * slope:
        return None
    return float(slope), float(icpt), k, resid


def empty_slots(t: np.ndarray, x: np.ndarray, jitter: Jitter) -> np.ndarray:
    """Times of the slots of a jittered clock (`jittered_period`) that hold no finite sample:
    a jittered interval may exceed 1.5 periods with nothing missing, so slots, not intervals,
    tell the missing samples."""
    k = np.rint((t - jitter.offset) / jitter.ts_s).astype(np.int64)
    held = np.unique(k[np.isfinite(x)])
    if held.size == 0:
        return np.empty(0)
    missing = np.setdiff1d(np.arange(k.min(), k.max() + 1), held)
    return jitter.offset + missing * jitter.ts_s


def irregularity(t: np.ndarray, ts_s: float, max_gap_s: float) -> float:
    """Fraction of sample intervals (gaps excluded) that differ from ``ts_s`` by more than 10 %."""
    d = np.diff(t)
    d = d[(d > 0) & (d <= max_gap_s)]
    if d.size == 0:
        return 0.0
    return float(np.count_nonzero(np.abs(d - ts_s) > 0.1 * ts_s) / d.size)


def to_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray, max_gap_s: float,
            step: float | None = None, bad_gap_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Values of a sorted series on ``grid``: linear inside gaps up to ``max_gap_s``, NaN beyond.

    ``grid`` is increasing in steps of ``step`` (default ``grid[1] - grid[0]``); it may skip
    stretches where there is no data. ``bad_gap_s`` (default ``max_gap_s``) limits the gaps that
    hold a bad sample: a tag archived by exception gets a long ``max_gap_s``, but a bad value
    between its archive points marks an outage, not a stretch without change. Returns the gridded
    values and a mask of the grid points filled by interpolation across a missing or bad sample.
    """
    ok = np.isfinite(x)
    tv, xv = (t, x) if ok.all() else (t[ok], x[ok])
    if tv.size == grid.size and tv.size > 1 and np.array_equal(tv, grid):
        return xv.copy(), np.zeros(grid.shape, bool)     # every grid point is a sample: nothing to interpolate
    out = np.full(grid.shape, np.nan)
    if tv.size == 0:
        return out, np.zeros(grid.shape, bool)
    if tv.size == 1:
        hit = np.abs(grid - tv[0]) < 1e-6 * max(1.0, abs(tv[0])) + 1e-9
        out[hit] = xv[0]
        return out, np.zeros(grid.shape, bool)
    j = np.searchsorted(tv, grid, side="right")
    inside = (j > 0) & (j < tv.size)
    jj = np.clip(j, 1, tv.size - 1)
    t0, t1 = tv[jj - 1], tv[jj]
    span = t1 - t0
    if step is None:
        step = float(grid[1] - grid[0]) if grid.size > 1 else max_gap_s
    # a last sample a hair off the grid (times rounded to the millisecond) still ends the series
    tol = max(1e-6 * max(1.0, float(np.nanmax(np.abs(grid))) * 1e-6), END_TOLERANCE * step)
    exact_end = np.abs(grid - tv[-1]) <= 1e-9 + tol
    w = np.where(span > 0, (grid - t0) / np.where(span > 0, span, 1.0), 0.0)
    vals = xv[jj - 1] + w * (xv[jj] - xv[jj - 1])
    limit: float | np.ndarray = max_gap_s
    if bad_gap_s is not None and not ok.all():
        n_bad = np.cumsum(~ok)[ok]                   # bad samples before each good one
        limit = np.where(n_bad[jj] > n_bad[jj - 1], bad_gap_s, max_gap_s)
    good = inside & (span <= limit * (1 + 1e-9))
    out[good] = vals[good]
    out[exact_end] = xv[-1]
    on_sample = (j > 0) & (np.abs(grid - t0) <= 1e-6 * step)
    out[on_sample] = xv[jj - 1][on_sample]   # a grid point on a sample keeps it, even beside a long gap
    # interpolation across a missing/bad sample: interval longer than 1.5 grid steps
    return out, good & (span > 1.5 * step) & ~on_sample


def hold_grid(t: np.ndarray, x: np.ndarray, grid: np.ndarray, step: float | None = None) -> np.ndarray:
    """A state signal (a controller's mode) on ``grid`` by zero-order hold: each grid point takes
    the last sample at or before it, NaN before the first sample and after a bad (NaN) one.

    A mode tag is archived when it changes (a PI digital state, exported as recorded values): between
    two events the state holds, it does not ramp, and a silence of hours is a loop left alone, not
    a gap. ``t`` must be sorted.
    """
    out = np.full(grid.shape, np.nan)
    if t.size == 0:
        return out
    if step is None:
        step = float(grid[1] - grid[0]) if grid.size > 1 else 1.0
    # a sample stamped a hair after its grid point (times rounded to the millisecond) still counts
    j = np.searchsorted(t, grid + 1e-6 * step, side="right") - 1
    have = j >= 0
    out[have] = x[j[have]]
    return out


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` index pairs of the True runs of a boolean array."""
    if mask.size == 0:
        return []
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts = np.flatnonzero(d == 1)
    stops = np.flatnonzero(d == -1)
    return list(zip(starts.tolist(), stops.tolist()))
