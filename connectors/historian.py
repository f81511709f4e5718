"""Historian exports: read a file into loop records, write a record as a wide CSV.

This module starts with the common *wide* layout (a header row, a timestamp column, one column per
signal); other layouts are added beside it.
"""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import IO, Iterable

import numpy as np

from diagnose.errors import ConnectorError
from diagnose.record import LoopRecord

from .columns import role_of, split_tag

EPOCH = datetime(2026, 1, 1, tzinfo=timezone.utc)


def _parse_time(text: str) -> float:
    """Seconds since an arbitrary origin from ISO 8601 or a plain number of seconds."""
    text = text.strip()
    try:
        return float(text)
    except ValueError:
        pass
    dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.timestamp()


def read_wide(source: str | os.PathLike | IO[str], *, op: str | None = None, pv: str | None = None,
              sp: str | None = None, mv: str | None = None, ts: str | None = None,
              ts_s: float | None = None, name: str | None = None) -> LoopRecord:
    """Read a wide CSV (header row, timestamp column, OP/PV[/SP/MV] columns) into a record.

    Parameters
    ----------
    source : path or text file object
    op, pv, sp, mv : str, optional
        Column names that override the naming rule in `connectors.columns`.
    ts : str, optional
        Name of the timestamp column.
    ts_s : float, optional
        Sample period in seconds; taken from the timestamps when not given.
    name : str, optional
        Loop name; defaults to the tag prefix of the OP/PV columns or the file stem.
    """
    path = None if hasattr(source, "read") else str(source)
    label = path or getattr(source, "name", "<stream>")
    if path is not None:
        if not os.path.exists(path):
            raise ConnectorError("file not found", path=label)
        fh: IO[str] = open(path, newline="", encoding="utf-8-sig")
    else:
        fh = source  # type: ignore[assignment]
    try:
        rows = list(csv.reader(fh))
    finally:
        if path is not None:
            fh.close()
    if not rows:
        raise ConnectorError("file is empty", path=label)
    header = [h.strip() for h in rows[0]]
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    if not body:
        raise ConnectorError("header only, no data rows", path=label, line=1)
    overrides = {"op": op, "pv": pv, "sp": sp, "mv": mv, "time": ts}
    cols: dict[str, int] = {}
    for role, col in overrides.items():
        if col is not None:
            if col not in header:
                raise ConnectorError(f"no column named {col!r} for {role.upper()} (columns: {', '.join(header)})",
                                     path=label, line=1)
            cols[role] = header.index(col)
    for i, h in enumerate(header):
        role = role_of(h)
        if role is None or overrides.get(role) is not None or i in cols.values():
            continue
        if role in cols:
            raise ConnectorError(f"columns {header[cols[role]]!r} and {h!r} both look like {role.upper()}; "
                                 f"choose one with --{role if role != 'time' else 'ts'}", path=label, line=1)
        cols[role] = i
    for role in ("op", "pv"):
        if role not in cols:
            raise ConnectorError(f"no {role.upper()} column found (columns: {', '.join(header)}); "
                                 f"name it with --{role}", path=label, line=1)
    data: dict[str, np.ndarray] = {}
    for role, idx in cols.items():
        if role == "time":
            continue
        vals = np.empty(len(body))
        for k, row in enumerate(body):
            try:
                vals[k] = float(row[idx])
            except (ValueError, IndexError):
                vals[k] = math.nan
        data[role] = vals
    times = None
    if "time" in cols:
        times = np.empty(len(body))
        for k, row in enumerate(body):
            try:
                times[k] = _parse_time(row[cols["time"]])
            except (ValueError, IndexError):
                raise ConnectorError(f"cannot read timestamp {row[cols['time']] if len(row) > cols['time'] else ''!r}",
                                     path=label, line=k + 2, column=header[cols["time"]]) from None
    if ts_s is None:
        if times is None or len(times) < 2:
            raise ConnectorError("no timestamp column and no sample period; give --ts SECONDS", path=label)
        ts_s = float(np.median(np.abs(np.diff(times))))
        if not ts_s > 0:
            raise ConnectorError("timestamps do not advance; give --ts SECONDS", path=label)
    finite = np.all(np.isfinite(np.vstack(list(data.values()))), axis=0)
    if not finite.any():
        raise ConnectorError("no row has numeric values in every role column", path=label)
    keep = finite
    tag = split_tag(header[cols["op"]])[0] or split_tag(header[cols["pv"]])[0]
    loop = name or tag or (Path(path).stem if path else "LOOP")
    start = None
    if times is not None and abs(times[0]) > 1e8:
        start = datetime.fromtimestamp(times[0], tz=timezone.utc).isoformat()
    return LoopRecord(name=loop, ts_s=ts_s, op=data["op"][keep], pv=data["pv"][keep],
                      sp=data["sp"][keep] if "sp" in data else None,
                      mv=data["mv"][keep] if "mv" in data else None, start=start,
                      units={"op": "%", "mv": "%"}, source=label,
                      meta={"format": "wide", "columns": {r: header[i] for r, i in cols.items()}})


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file so that a reader sees the old or the new content, never half of it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def format_wide(record: LoopRecord, *, start: datetime = EPOCH) -> str:
    """A record as wide CSV text: ``time,<loop>.OP,<loop>.PV[,<loop>.SP][,MV]``."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    roles = [("op", f"{record.name}.OP"), ("pv", f"{record.name}.PV")]
    if record.sp is not None:
        roles.append(("sp", f"{record.name}.SP"))
    if record.mv is not None:
        roles.append(("mv", f"{record.name}.POS"))
    w.writerow(["time"] + [h for _, h in roles])
    series = [getattr(record, r) for r, _ in roles]
    for k in range(record.n):
        t = (start + timedelta(seconds=k * record.ts_s)).isoformat().replace("+00:00", "Z")
        w.writerow([t] + [f"{s[k]:.6g}" for s in series])
    return buf.getvalue()


def write_wide(record: LoopRecord, path: str | os.PathLike) -> None:
    """Write a record as a wide CSV file (atomically)."""
    atomic_write_text(path, format_wide(record))


def read_many(paths: Iterable[str | os.PathLike], **kwargs) -> list[LoopRecord]:
    return [read_wide(p, **kwargs) for p in paths]
