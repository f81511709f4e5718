"""pandas DataFrames into loop records, the way files are read.

A frame's time is its `DatetimeIndex`, or a time column (named like one, or given with ``ts``), or
its row number times ``ts_s`` (evenly spaced rows). Its other columns are signals: which is OP,
PV, SP, MV or mode follows the naming rule of `connectors.columns` (or ``op=``, ``pv=``...), and
everything after that (duplicates, gaps, segments, the uniform grid, findings) is the file
reader's own (`connectors.records`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from diagnose.errors import ConnectorError, DataError
from diagnose.record import LoopRecord

from .columns import FRAME_LABEL, role_of
from .layouts import Series, Table, blank_cells, is_time_header
from .records import build_records, specs_from_table
from .textio import numbers
from .timebase import localise, parse_times, zone_of

LABEL = FRAME_LABEL
#: The column name a reader's error carries when the times were the frame's index (the index has no
#: column to name: its own name, or pandas' "index", reads as a column that is not there).
INDEX = "<index>"
FRAME_OPTIONS = ("op", "pv", "sp", "mv", "mode", "time", "ts", "ts_s", "name", "tz", "dst", "dayfirst", "loop",
                 "max_gap_s", "min_samples", "max_samples")


def _seconds(values: Any, tz: str | None, dst: str, column: str) -> tuple[np.ndarray, bool]:
    """UTC epoch seconds of datetimes (naive ones are local times in ``tz``), or seconds of timedeltas."""
    idx = pd.Index(values)
    if isinstance(idx, pd.TimedeltaIndex):
        return np.array(idx.as_unit("us").asi8, dtype=float) / 1e6, False
    idx = pd.DatetimeIndex(idx)
    if idx.tz is not None:
        us = idx.tz_convert("UTC").as_unit("us").asi8
        out = np.where(idx.isna(), np.nan, us / 1e6)
        return out, True
    us = np.array(idx.as_unit("us").asi8, dtype=np.int64)
    rows = np.flatnonzero(~idx.isna())
    out = np.full(len(idx), np.nan)
    out[rows] = localise(us, rows, zone_of(tz), dst, LABEL, column, lambda k: k + 1)   # row k is "line" k + 1
    return out, True


def _zone(values: Any, tz: str | None) -> str | None:
    """How datetimes were read, as `parse_times` says it: "offset" for aware ones, else the zone of
    naive ones (None for timedeltas)."""
    dtype = getattr(values, "dtype", None)
    if pd.api.types.is_timedelta64_dtype(dtype):
        return None
    return "offset" if getattr(dtype, "tz", None) is not None else (tz or "UTC")


def table_from_frame(df: pd.DataFrame, options: dict) -> Table:
    """The frame's columns as the named time series of a `Table` (what a layout parser gives)."""
    if not isinstance(df, pd.DataFrame):
        raise DataError(f"expected a pandas DataFrame, got {type(df).__name__}")
    if isinstance(df.columns, pd.MultiIndex):
        raise DataError("the frame has several column levels; flatten them to one name per column")
    if not len(df):
        raise DataError("the frame has no rows")
    if not isinstance(df.index, pd.MultiIndex) and (df.index.dtype == object
                                                    or pd.api.types.is_string_dtype(df.index.dtype)):
        # times left as text in the index (read_csv without parse_dates): read them as a time column
        named = df.index.name is not None
        name = str(df.index.name) if named else INDEX       # errors then place it in "the frame's index"
        df = df.reset_index(names=[name if name not in map(str, df.columns) else INDEX])
        # with ts_s given, only an index named like a time column is one (labels are no time axis)
        text_index = not options.get("ts_s") or (named and (is_time_header(name) or role_of(name) == "time"))
    else:
        text_index = False
    names = [str(c) for c in df.columns]
    tz, dst = options.get("tz"), options.get("dst", "infer")
    t = None
    absolute = False
    tfmt = tzone = None
    time_col = None
    guessed = None
    if options.get("ts"):
        if options["ts"] not in names:
            raise DataError(f"no column named {options['ts']!r} for the time (columns: {', '.join(names)})")
        time_col = names.index(options["ts"])
    elif isinstance(df.index, (pd.DatetimeIndex, pd.TimedeltaIndex)):
        t, absolute = _seconds(df.index, tz, dst, INDEX)
        tfmt, tzone = "index", _zone(df.index, tz)
    elif text_index:
        time_col = 0          # the index's times, whatever its name (a ts_s given resamples them)
    elif not options.get("ts_s"):
        time_col = next((j for j, n in enumerate(names) if role_of(n) == "time" or is_time_header(n)
                         and role_of(n) is None), None)
    if time_col is not None:
        col = df.iloc[:, time_col]
        if pd.api.types.is_datetime64_any_dtype(col.dtype) or pd.api.types.is_timedelta64_dtype(col.dtype):
            t, absolute = _seconds(col, tz, dst, names[time_col])
            tfmt, tzone = "datetime", _zone(col, tz)
        else:
            values = col.to_numpy()
            pt = parse_times(values if values.dtype.kind in "fiu" else values.astype(object), tz=tz, dst=dst,
                             label=LABEL, column=names[time_col], lines=np.arange(len(df)) + 1,
                             dayfirst=options.get("dayfirst"))
            t, absolute, tfmt, tzone = pt.seconds, pt.absolute, pt.fmt, pt.tz
            guessed = pt.order_guessed and dict(pt.order_guessed, column=names[time_col])
    series = []
    for j, name in enumerate(names):
        if j == time_col:
            continue
        values = df.iloc[:, j].to_numpy()
        if values.dtype == bool:
            values = values.astype(float)
        elif values.dtype.kind not in "fiu":
            values = values.astype(object)
        num = numbers(values)
        series.append(Series(name=name, t=t, x=num.values, n_text=num.n_text, n_nonfinite=num.n_nonfinite,
                             n_blank=num.n_blank, examples=num.examples, first_line=None, column=name,
                             cells=num.text, blank=blank_cells(num)))
    meta = {"format": "dataframe", "time_format": tfmt, "time_zone": tzone,
            "time_columns": [names[time_col]] if time_col is not None else []}
    if guessed:
        meta["date_order_guessed"] = guessed
    return Table(series, LABEL, absolute, meta, raw_columns=names)


def _in_frame(exc: ConnectorError) -> str:
    """A reader's error about a frame, placed by column and row position: the reader counts a
    file's lines from 1 (the frame's rows are its lines), and a frame has no file to name."""
    if exc.path != LABEL:
        return str(exc)
    where = ["the frame's index" if exc.column == INDEX else f"column {exc.column!r}"] if exc.column is not None else []
    if exc.line is not None:
        where.append(f"row {exc.line - 1}")
    return (", ".join(where) + ": " if where else "") + exc.message


def records_from_frame(df: pd.DataFrame, **options: Any) -> list[LoopRecord]:
    """Every loop of a DataFrame as records, one per loop per contiguous segment (see `read_loops`
    for the options; ``tags`` and ``fmt`` do not apply to frames).

    Raises
    ------
    diagnose.errors.DataError
        One line saying what in the frame is wrong.
    """
    unknown = set(options) - set(FRAME_OPTIONS)
    if unknown:
        raise DataError(f"unknown options {sorted(unknown)}; allowed: {', '.join(FRAME_OPTIONS)}")
    options = {k: v for k, v in options.items() if v is not None}
    if "time" in options:
        options.setdefault("ts", options.pop("time"))
    if not options.get("name") and isinstance(df, pd.DataFrame) and df.attrs.get("name"):
        options["name"] = str(df.attrs["name"])      # what LoopRecord.to_frame() writes
    try:
        table = table_from_frame(df, options)
        specs = specs_from_table(table, options, None)
        if options.get("loop"):
            want = str(options["loop"]).lower()
            found = [s.name for s in specs]
            specs = [s for s in specs if s.name.lower() == want]
            if not specs:
                raise DataError(f"no loop named {options['loop']!r} in the frame (loops: {', '.join(found)})")
        records: list[LoopRecord] = []
        for spec in specs:
            records.extend(build_records(spec, options))
    except ConnectorError as exc:
        raise DataError(_in_frame(exc)) from None
    return [r.replace(source=None) if r.source == LABEL else r for r in records]
