"""Historian exports: read a file into loop records, write a record as a wide CSV.

`read_wide` reads the common *wide* layout (through `connectors.read_records`, which handles every
layout); `format_wide`/`write_wide` write a record as ``time,<loop>.OP,<loop>.PV[,<loop>.SP][,<loop>.POS]``
with ISO 8601 UTC times, and `atomic_write` is the atomic-write helper every output uses.
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import IO

from diagnose.record import LoopRecord

EPOCH = datetime(2026, 1, 1, tzinfo=timezone.utc)


def read_wide(source: str | os.PathLike | IO[str], *, op: str | None = None, pv: str | None = None,
              sp: str | None = None, mv: str | None = None, ts: str | None = None,
              ts_s: float | None = None, name: str | None = None, **options) -> LoopRecord:
    """Read a wide CSV (header row, timestamp column, OP/PV[/SP/MV] columns) into one record.

    A thin wrapper over `connectors.read_records` with ``fmt="wide"`` that returns the longest
    segment of the first loop; see `read_records` for the options.

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
    from . import read_records

    options.setdefault("fmt", "wide")
    recs = read_records(source, op=op, pv=pv, sp=sp, mv=mv, ts=ts, ts_s=ts_s, name=name, **options)
    first = recs[0].name
    return max((r for r in recs if r.name == first), key=lambda r: r.n)


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def atomic_write(path: str | os.PathLike, data: bytes | str) -> None:
    """Write a file so that a reader (or a killed job) sees the old or the new content, never half.

    Text is written as UTF-8. The file gets the permissions the umask allows (as ``open`` would),
    not the 0600 of the temporary file it is renamed from.
    """
    from diagnose.errors import ConnectorError

    path = Path(path)
    # the temporary file's name in an OSError means nothing to the user: name the file asked for
    if path.is_dir():
        raise ConnectorError("is a folder; give the name of the file to write", path=str(path))
    above = next((p for p in path.parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise ConnectorError(f"cannot write: {above} is a file, not a folder", path=str(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise ConnectorError(f"cannot write: {exc.strerror or exc}", path=str(path)) from None
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode("utf-8") if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, ConnectorError):
            raise ConnectorError(f"cannot write: {exc.strerror or exc}", path=str(path)) from None
        raise


def format_wide(record: LoopRecord, *, start: datetime | None = None) -> str:
    """A record as wide CSV text: ``time,<loop>.OP,<loop>.PV[,<loop>.SP][,MV]``, in UTC from
    ``start``, else from the record's own start, else from `EPOCH`."""
    if start is None:
        start = EPOCH
        if record.start:
            start = datetime.fromisoformat(str(record.start).replace("Z", "+00:00"))
            start = start.replace(tzinfo=timezone.utc) if start.tzinfo is None else start.astimezone(timezone.utc)
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
    atomic_write(path, format_wide(record))
