"""Write records as wide historian CSV files plus a ``labels.csv`` with the truth.

One file per loop: ``time,TAG.OP,TAG.PV,TAG.SP[,TAG.POS]`` with ISO-8601 UTC timestamps. The stem
position is written as ``TAG.POS`` because this project's naming rule reads a tag-style ``.MV``
column as the controller output (DCS convention, see docs/connectors.md). Files are written to a
temporary name and renamed, so a crash never leaves a half-written file under the final name.
"""

from __future__ import annotations

import csv
import io
import math
import os
from datetime import datetime, timedelta, timezone
from typing import Iterable

import numpy as np

__all__ = ["write_loops", "LEAD_COLUMNS"]

LEAD_COLUMNS = ("file", "name", "label", "sticky", "scenario", "law", "S_pct", "J_pct", "class", "process",
                "integrating", "ts_s", "n", "definition")
START = datetime(2026, 1, 1, tzinfo=timezone.utc)


def _atomic_write(path: str, text: str) -> None:
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(text)
    os.replace(tmp, path)


def _stamps(n: int, ts_s: float) -> list[str]:
    whole = float(ts_s).is_integer()
    fmt = "%Y-%m-%dT%H:%M:%SZ" if whole else "%Y-%m-%dT%H:%M:%S.%fZ"
    return [(START + timedelta(seconds=k * ts_s)).strftime(fmt) for k in range(n)]


def loop_csv(loop, *, with_mv: bool = False) -> str:
    """The wide CSV text of one `SimLoop`."""
    tag = loop.name
    cols = [loop.op, loop.pv, loop.sp] + ([loop.mv] if with_mv else [])
    head = ["time", f"{tag}.OP", f"{tag}.PV", f"{tag}.SP"] + ([f"{tag}.POS"] if with_mv else [])
    stamps = _stamps(loop.n, loop.ts_s)
    data = np.column_stack(cols)
    lines = [",".join(head)]
    for t, row in zip(stamps, data):
        lines.append(t + "," + ",".join(f"{v:.10g}" for v in row))
    return "\n".join(lines) + "\n"


def _cell(v) -> str:
    if isinstance(v, bool) or isinstance(v, np.bool_):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return ";".join(_cell(x) for x in v)
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    if v is None:
        return ""
    return str(v)


def write_loops(loops: Iterable, out_dir: str | os.PathLike, *, with_mv: bool = False) -> list[str]:
    """Write each loop to ``out_dir/<name>.csv`` and the truth of all of them to ``out_dir/labels.csv``.

    Parameters
    ----------
    loops : iterable of SimLoop
    out_dir : path
        Created if missing.
    with_mv : bool
        Also write the true stem position (``TAG.POS``).

    Returns
    -------
    list of str
        Paths of the loop files, in order (``labels.csv`` not included).
    """
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    paths, rows = [], []
    for loop in loops:
        fname = f"{loop.name}.csv"
        path = os.path.join(out_dir, fname)
        _atomic_write(path, loop_csv(loop, with_mv=with_mv))
        paths.append(path)
        row = dict(loop.meta)
        row.update(file=fname, name=loop.name, label="sticky" if loop.sticky else "not_sticky",
                   sticky=loop.sticky, scenario=row.get("scenario", loop.kind), ts_s=loop.ts_s, n=loop.n)
        rows.append(row)
    keys = list(LEAD_COLUMNS) + sorted({k for r in rows for k in r} - set(LEAD_COLUMNS))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(keys)
    for r in rows:
        w.writerow([_cell(r.get(k)) for k in keys])
    _atomic_write(os.path.join(out_dir, "labels.csv"), buf.getvalue())
    return paths
