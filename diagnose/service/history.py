"""Results of every run in an SQLite database: the S/J/class trend of each loop.

The database lives at `default_db_path()` (``$STICTION_HOME/history.sqlite``, else
``$XDG_DATA_HOME/stiction/history.sqlite``, else ``~/.local/share/stiction/history.sqlite``) unless a
path is given (``--db``). It runs in WAL mode so readers (``stiction history``, batch workers
looking up a loop's past) never block the writer, and each write is one transaction: a run killed
half-way leaves every earlier result intact and nothing half-written. A result already stored (same
loop, input hash and tool version) is not stored twice, so a resumed batch does not duplicate rows.

Runs are filed under the loop's tag and ordered by the end of the record they diagnosed
(``data_end``), not by when the diagnosis ran (``run_at``, kept beside it): a month of exports
back-filled in one night makes a month of history. A database from before ``data_end`` existed is
migrated in place the first time it is opened for writing.
"""

from __future__ import annotations

import json
import os
import sqlite3
import statistics
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Sequence

from ..errors import StictionError
from ..plain import finite_or_none, pct_per_op_unit, percent, sj_decimals, units_in_words

if TYPE_CHECKING:
    from .pipeline import Diagnosis

SCHEMA_VERSION = 4

#: A loop is "degrading" when S rose at each of the last `DEGRADE_RUNS` - 1 steps by at least
#: `DEGRADE_STEP_PCT` and by at least `DEGRADE_TOTAL_PCT` in all (% of valve span).
DEGRADE_RUNS = 3
DEGRADE_STEP_PCT = 0.05
DEGRADE_TOTAL_PCT = 0.3

#: The verdict's persistence is counted over a loop's last `PERSIST_RUNS` runs (this one included).
PERSIST_RUNS = 7

_DDL = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY,
    loop TEXT NOT NULL,
    run_at TEXT NOT NULL,
    data_start TEXT,
    data_end TEXT,
    source TEXT,
    input_hash TEXT NOT NULL DEFAULT '',
    data_hash TEXT,
    tool_version TEXT NOT NULL DEFAULT '',
    status TEXT NOT NULL DEFAULT 'ok',
    class TEXT,
    S_pct REAL, S_lo REAL, S_hi REAL,
    J_pct REAL, J_lo REAL, J_hi REAL,
    sj_units TEXT,
    confidence REAL,
    severity REAL,
    oscillation_period_s REAL,
    verdict TEXT,
    stiction INTEGER,
    stiction_probability REAL,
    result_json TEXT,
    UNIQUE (loop, input_hash, tool_version)
);
CREATE INDEX IF NOT EXISTS runs_loop ON runs (loop, run_at);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT);
"""

_COLS = ("loop", "run_at", "data_start", "data_end", "source", "input_hash", "data_hash", "tool_version", "status", "class",
         "S_pct", "S_lo", "S_hi", "J_pct", "J_lo", "J_hi", "sj_units", "confidence", "severity",
         "oscillation_period_s", "verdict", "stiction", "stiction_probability", "result_json")


def default_db_path() -> Path:
    """Where the history lives unless ``--db`` says otherwise."""
    home = os.environ.get("STICTION_HOME")
    if home:
        return Path(home) / "history.sqlite"
    xdg = os.environ.get("XDG_DATA_HOME")
    base = Path(xdg) if xdg else Path.home() / ".local" / "share"
    return base / "stiction" / "history.sqlite"


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def _parse_time(text: Any) -> datetime | None:
    if not text:
        return None
    try:
        t = datetime.fromisoformat(str(text).strip().replace("Z", "+00:00"))
    except ValueError:
        return None
    return t if t.tzinfo is not None else t.replace(tzinfo=timezone.utc)


def utc_text(text: Any) -> Any:
    """A stored time as UTC ISO 8601 ending in ``Z``, the form the readers give a record's start
    (rows written before this form ended in ``+00:00``); anything that is not a time as it is."""
    t = _parse_time(text)
    if t is None:
        return text
    return t.astimezone(timezone.utc).isoformat().replace("+00:00", "Z")


def end_of_record(start: Any, n: Any, ts_s: Any) -> str | None:
    """UTC time of the last sample (``...Z``) of a record of ``n`` samples every ``ts_s``
    seconds from ``start`` (ISO 8601); None when the start is unknown (an export of sample indices)."""
    t0 = _parse_time(start)
    if t0 is None:
        return None
    try:
        n, ts = int(n or 0), float(ts_s or 0.0)
    except (TypeError, ValueError):
        return None
    if n <= 0 or not ts > 0:
        return None
    from datetime import timedelta

    end = t0 + timedelta(seconds=(n - 1) * ts)
    return end.astimezone(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z")


def record_end(result: Mapping[str, Any]) -> str | None:
    """`end_of_record` of a stored result (``LOOP.json`` or a history row's ``result_json``)."""
    stored = result.get("record")
    rec: Mapping[str, Any] = stored if isinstance(stored, Mapping) else {}
    return end_of_record(rec.get("start"), rec.get("n") or result.get("n_samples"),
                         rec.get("ts_s") or result.get("ts_s"))


def history_loop(name: str) -> str:
    """The name a loop's runs are filed under: its tag, file-safe (a batch report may carry a
    longer name when two inputs hold the same tag; both belong to one history)."""
    from .batch import safe_name

    return safe_name(name)


def row_from_diagnosis(diag: Diagnosis, *, run_at: str | None = None, input_hash: str | None = None) -> dict[str, Any]:
    """The history row of one loop's diagnosis (the columns of the ``runs`` table)."""
    ident = diag.identification
    rec = diag.record
    si = ident.S_interval_pct or (None, None)
    ji = ident.J_interval_pct or (None, None)
    result = diag.to_dict()
    return {
        "loop": history_loop(ident.loop),
        "run_at": run_at or utc_now(),
        "data_start": utc_text(rec.start),
        "data_end": end_of_record(rec.start, rec.n, rec.ts_s),
        "source": rec.source or ident.source,
        "input_hash": input_hash or diag.input_hash or "",
        "data_hash": stored_data_hash(result),
        "tool_version": diag.tool_version,
        "status": "ok",
        "class": ident.cls,
        "S_pct": finite_or_none(ident.S_pct), "S_lo": finite_or_none(si[0]), "S_hi": finite_or_none(si[1]),
        "J_pct": finite_or_none(ident.J_pct), "J_lo": finite_or_none(ji[0]), "J_hi": finite_or_none(ji[1]),
        "sj_units": ident.op_units,
        "confidence": finite_or_none(ident.confidence),
        "severity": finite_or_none(diag.severity.score),
        "oscillation_period_s": finite_or_none(ident.oscillation.period_s),
        "verdict": diag.verdict_text,
        **verdict_of(ident),
        "result_json": json.dumps(result, separators=(",", ":"), allow_nan=False),
    }


def verdict_of(ident: Any) -> dict[str, Any]:
    """An identification's verdict as the history stores it (the columns `sticky_runs` counts):
    a loop's runs so far plus this one make its persistence."""
    # a record no test could judge says nothing either way: it is no "healthy" run to count
    if ident.nothing_judged:
        return {"stiction": None, "stiction_probability": None}
    return {"stiction": int(bool(ident.stiction)), "stiction_probability": finite_or_none(ident.stiction_probability)}


def stored_units(result: Mapping[str, Any]) -> str | None:
    """The units of a stored result's S and J (``sj_units``; results of releases before it have
    ``sj_in_op_units`` at most): None for % of span as far as the result can tell."""
    units = result.get("sj_units")
    if isinstance(units, str) and units:
        return units
    return "OP units" if result.get("sj_in_op_units") is True else None


def stored_data_hash(result: Mapping[str, Any]) -> str | None:
    """The digest of a stored result's samples (``record.data_hash``, `LoopRecord.data_hash`);
    None for results of releases before it."""
    rec = result.get("record")
    digest = rec.get("data_hash") if isinstance(rec, Mapping) else None
    return digest if isinstance(digest, str) else None


def run_units(row: Mapping[str, Any]) -> str:
    """The units of a stored run's S and J and their intervals (`Identification.op_units`):
    ``"% of span"``, ``"OP units"`` or ``"fraction of span"``. Rows stored before the units were
    kept are in % of span."""
    return row.get("sj_units") or "% of span"


def size_pct(row: Mapping[str, Any], key: str = "S_pct") -> float | None:
    """A stored run's S (or another size column) in % of span where its units say how
    (`diagnose.plain.pct_per_op_unit`; OP's own units are taken as they are)."""
    v = finite_or_none(row.get(key))
    return None if v is None else v * pct_per_op_unit(run_units(row))


def _flag(value: Any) -> int | None:
    return int(value) if isinstance(value, bool) else None


def _pair(value: Any) -> tuple[float | None, float | None]:
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return finite_or_none(value[0]), finite_or_none(value[1])
    return None, None


def row_from_stored(result: Mapping[str, Any], *, run_at: str | None = None, input_hash: str | None = None,
                    status: str = "ok", error: str | None = None) -> dict[str, Any]:
    """The history row of a stored result: a ``LOOP.json`` of any schema in
    `diagnose.service.pipeline.READ_SCHEMAS` (a resumed batch files it again)."""
    stored = result.get("record")
    rec: Mapping[str, Any] = stored if isinstance(stored, Mapping) else {}
    slo, shi = _pair(result.get("S_interval"))
    jlo, jhi = _pair(result.get("J_interval"))
    sev = result.get("severity")
    osc = result.get("oscillation")
    # a record no test could judge said nothing either way: no verdict to count (`verdict_of`)
    warned = result.get("warnings")
    judged = not (isinstance(warned, list) and any(isinstance(w, Mapping) and w.get("code") == "nothing_judged"
                                                   for w in warned))
    return {
        "loop": history_loop(str(result.get("loop") or result.get("loop_id"))),
        "run_at": run_at or utc_now(),
        "data_start": utc_text(rec.get("start")),
        "data_end": record_end(result),
        "source": rec.get("source") or result.get("source"),
        "input_hash": input_hash or result.get("input_hash") or "",
        "data_hash": stored_data_hash(result),
        "tool_version": result.get("tool_version") or "",
        "status": status,
        "class": result.get("class"),
        **(dict(S_pct=finite_or_none(result.get("S")), S_lo=slo, S_hi=shi,
                J_pct=finite_or_none(result.get("J")), J_lo=jlo, J_hi=jhi) if judged else dict.fromkeys(SIZE_COLUMNS)),
        "sj_units": stored_units(result),
        "confidence": finite_or_none(result.get("confidence")),
        "severity": finite_or_none(sev.get("score")) if isinstance(sev, Mapping) else None,
        "oscillation_period_s": finite_or_none(osc.get("period_s")) if isinstance(osc, Mapping) else None,
        "verdict": error if status != "ok" else result.get("verdict"),
        "stiction": _flag(result.get("stiction")) if status == "ok" and judged else None,
        "stiction_probability": finite_or_none(result.get("stiction_probability")) if status == "ok" and judged
        else None,
        "result_json": json.dumps(result, separators=(",", ":"), allow_nan=False) if status == "ok" else None,
    }


#: How long a write waits for a lock another process holds (a batch's transaction, a backup).
BUSY_TIMEOUT_S = 30.0


class HistoryBusy(StictionError):
    """The history database stayed locked by another process for longer than the wait allowed."""


def _is_busy(exc: sqlite3.Error) -> bool:
    text = str(exc).lower()
    return isinstance(exc, sqlite3.OperationalError) and ("locked" in text or "busy" in text)


class History:
    """The results database.

    Parameters
    ----------
    path : path-like, optional
        SQLite file; `default_db_path()` when None. Parent folders are created.
    readonly : bool
        Open an existing database for reading only (raises when it does not exist).
    busy_timeout_s : float
        How long opening and each write wait for a lock another process holds; past it,
        `HistoryBusy` (a busy database is not a broken one).
    """

    def __init__(self, path: str | os.PathLike | None = None, *, readonly: bool = False,
                 busy_timeout_s: float = BUSY_TIMEOUT_S) -> None:
        self.path = Path(path) if path is not None else default_db_path()
        if self.path.is_dir():  # sqlite says only "disk I/O error" of a folder
            raise StictionError(f"{self.path}: is a folder; --db takes the database file (for example "
                                f"{self.path / 'history.sqlite'})")
        try:
            if readonly:
                if not self.path.exists():
                    raise StictionError(f"{self.path}: no history database here yet; run "
                                        "`stiction batch` (or give --db)")
                self.conn = self._connect_readonly()
            else:
                self._check_writable()
                self.conn = sqlite3.connect(self.path, timeout=busy_timeout_s)
                self.conn.execute("PRAGMA journal_mode=WAL")
                self.conn.execute("PRAGMA synchronous=NORMAL")
                with self.conn:
                    self.conn.executescript(_DDL)
                    self._migrate()
                    self.conn.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)",
                                      (str(SCHEMA_VERSION),))
            self._columns = {r[1] for r in self.conn.execute("PRAGMA table_info(runs)")}
        except sqlite3.DatabaseError as exc:
            if _is_busy(exc):
                raise self._busy(f"for {busy_timeout_s:g} s") from None
            raise StictionError(f"{self.path}: not a usable history database ({exc}); give another "
                                "path with --db") from None
        self.conn.row_factory = sqlite3.Row

    def _connect_readonly(self) -> sqlite3.Connection:
        """A read-only connection. A WAL database needs its ``-shm`` file, which SQLite cannot create
        in a folder it may not write (a read-only share, a copy kept by another user): there no
        process can be writing the file either, so it is opened as immutable."""
        conn = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=30)
        try:
            conn.execute("PRAGMA schema_version").fetchone()
            return conn
        except sqlite3.OperationalError:
            if os.access(self.path.parent, os.W_OK):
                raise
            conn.close()
            return sqlite3.connect(f"file:{self.path}?mode=ro&immutable=1", uri=True, timeout=30)

    def _check_writable(self) -> None:
        """Say why the database cannot be written (a read-only folder or file, no permission) in
        one line naming it, rather than SQLite's "unable to open database file"."""
        parent = self.path.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StictionError(f"{self.path}: cannot create the history database's folder {parent}: "
                                f"{exc.strerror or exc}; give another path with --db (or --no-history)") from None
        # SQLite writes the -wal and -shm files beside the database: the folder must be writable too
        for target, what in ((parent, "its folder"), (self.path, "the database file")):
            if target.exists() and not os.access(target, os.W_OK):
                raise StictionError(f"{self.path}: cannot write the history database: {what} is read-only "
                                    "(or not yours); give another path with --db (or --no-history)")

    def _busy(self, when: str) -> HistoryBusy:
        return HistoryBusy(f"{self.path}: the history database stayed locked by another process (a batch "
                           f"storing its results, a backup) {when}")

    def _failed(self, exc: sqlite3.Error, doing: str) -> StictionError:
        if _is_busy(exc):   # busy, not damaged: nothing to check in the file
            return self._busy(f"while {doing}")
        return StictionError(f"{self.path}: history database error while {doing} ({exc}); "
                             "check the file (`sqlite3 FILE 'PRAGMA integrity_check'`) or give another --db")

    def _migrate(self) -> None:
        """Bring a database of an earlier schema up to this one, in place (inside the caller's
        transaction: all of it or nothing). Version 2 added ``data_end``, filled here from each
        stored result; version 3 the verdict (``stiction``) and its probability, from the same;
        version 4 the units of S and J (``sj_units``) and the samples' digest (``data_hash``, from
        results that stored it)."""
        cols = {r[1] for r in self.conn.execute("PRAGMA table_info(runs)")}
        if "data_end" not in cols:
            self.conn.execute("ALTER TABLE runs ADD COLUMN data_end TEXT")
            for rid, res in self._stored_results():
                end = record_end(res)
                if end is not None:
                    self.conn.execute("UPDATE runs SET data_end = ? WHERE id = ?", (end, rid))
        if "stiction" not in cols:
            # version 3: the verdict and its probability as columns (the history's persistence)
            self.conn.execute("ALTER TABLE runs ADD COLUMN stiction INTEGER")
            self.conn.execute("ALTER TABLE runs ADD COLUMN stiction_probability REAL")
            for rid, res in self._stored_results():
                self.conn.execute("UPDATE runs SET stiction = ?, stiction_probability = ? WHERE id = ?",
                                  (_flag(res.get("stiction")), finite_or_none(res.get("stiction_probability")), rid))
        new = [c for c in ("sj_units", "data_hash") if c not in cols]
        if new:
            # version 4: S and J's units (OP logged as a fraction of span gives them in fractions),
            # and the digest of the samples (a record without times is told by it); each column on
            # its own, so that a database with one of them gets the other
            for c in new:
                self.conn.execute(f"ALTER TABLE runs ADD COLUMN {c} TEXT")
            for rid, res in self._stored_results():
                units, digest = stored_units(res), stored_data_hash(res)
                if units is not None or digest is not None:
                    self.conn.execute("UPDATE runs SET sj_units = ?, data_hash = ? WHERE id = ?", (units, digest, rid))
        self.conn.execute("CREATE INDEX IF NOT EXISTS runs_loop_end ON runs (loop, data_end)")
        self.conn.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))

    def _stored_results(self) -> list[tuple[int, dict[str, Any]]]:
        """(row id, stored result) of every run whose ``result_json`` reads as a JSON object: what
        a migration fills its new columns from (an unreadable one leaves them empty)."""
        out = []
        for rid, text in self.conn.execute("SELECT id, result_json FROM runs WHERE result_json IS NOT NULL").fetchall():
            try:
                res = json.loads(text)
            except ValueError:
                continue
            if isinstance(res, dict):
                out.append((rid, res))
        return out

    # -- context manager -------------------------------------------------------------------
    def __enter__(self) -> "History":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self.conn.close()

    # -- writing ---------------------------------------------------------------------------
    def add_rows(self, rows: Iterable[Mapping[str, Any]]) -> int:
        """Store rows (`row_from_diagnosis`, `row_from_stored`) in one transaction; returns how many were new."""
        sql = (f"INSERT INTO runs ({', '.join(_COLS)}) VALUES ({', '.join('?' for _ in _COLS)}) "
               "ON CONFLICT (loop, input_hash, tool_version) DO NOTHING")
        n = 0
        try:
            with self.conn:  # one transaction: all rows or none
                for row in rows:
                    cur = self.conn.execute(sql, tuple(row.get(c) for c in _COLS))
                    n += cur.rowcount
        except sqlite3.IntegrityError:
            raise   # a row the code built wrong, not a file in trouble
        except sqlite3.Error as exc:
            raise self._failed(exc, "storing runs") from None
        return n

    def add(self, diag: Diagnosis, **kw: Any) -> bool:
        """Store one loop's diagnosis (`row_from_diagnosis`); False when the same (loop, input,
        version) is already there."""
        return self.add_rows([row_from_diagnosis(diag, **kw)]) == 1

    # -- reading ---------------------------------------------------------------------------
    def runs(self, loop: str, *, limit: int | None = None, status: str | None = "ok",
             with_result: bool = False) -> list[dict[str, Any]]:
        """Runs of one loop in the order of their records' ends (runs of records without a time in
        the order they ran), oldest first; the last ``limit`` when given.

        A record diagnosed again (the same loop, start and end: an export corrected and re-run, or
        re-diagnosed by a later release; or the same samples again, `LoopRecord.data_hash`, which is
        how a record without times is told) counts once, by its latest run; the earlier rows stay in
        the database but would otherwise count one record twice in the trend, its persistence and
        its degradation."""
        cols = [c if c in self._columns else f"NULL AS {c}" for c in _COLS if with_result or c != "result_json"]
        where = "loop = ?" + (" AND status = ?" if status else "")
        args: list[Any] = [loop] + ([status] if status else [])
        end = "COALESCE(data_end, run_at)" if "data_end" in self._columns else "run_at"
        later = ("SELECT 1 FROM runs AS later WHERE later.loop = runs.loop"
                 + (" AND later.status = runs.status" if status else "")
                 + " AND (later.run_at > runs.run_at OR (later.run_at = runs.run_at AND later.id > runs.id))")
        if "data_end" in self._columns:
            where += (" AND NOT (data_start IS NOT NULL AND data_end IS NOT NULL AND EXISTS ("
                      f"{later} AND later.data_start = runs.data_start AND later.data_end = runs.data_end))")
        if "data_hash" in self._columns:
            # the same samples diagnosed again (by a later release, with other options): a record
            # without times has no start and end to tell it by
            where += f" AND NOT (data_hash IS NOT NULL AND EXISTS ({later} AND later.data_hash = runs.data_hash))"
        sql = f"SELECT {', '.join(cols)} FROM runs WHERE {where} ORDER BY {end} DESC, run_at DESC, id DESC"
        if limit:
            sql += f" LIMIT {int(limit)}"
        try:
            rows = [dict(r) for r in self.conn.execute(sql, args)]
        except sqlite3.Error as exc:
            raise self._failed(exc, f"reading the runs of {loop}") from None
        rows.reverse()
        for r in rows:   # one form whatever release wrote the row
            for key in ("run_at", "data_start", "data_end"):
                r[key] = utc_text(r[key])
            if r.get("stiction") is not None:
                r["stiction"] = bool(r["stiction"])   # stored as 0/1: the JSON says true/false
        return rows

    def loops(self) -> list[str]:
        try:
            return [r[0] for r in self.conn.execute("SELECT DISTINCT loop FROM runs ORDER BY loop")]
        except sqlite3.Error as exc:
            raise self._failed(exc, "listing the loops") from None

    def has(self, loop: str, input_hash: str, tool_version: str) -> bool:
        try:
            cur = self.conn.execute("SELECT 1 FROM runs WHERE loop = ? AND input_hash = ? AND tool_version = ?",
                                    (loop, input_hash, tool_version))
            return cur.fetchone() is not None
        except sqlite3.Error as exc:
            raise self._failed(exc, f"looking up a run of {loop}") from None


def previous_runs(db_path: str | os.PathLike | None, loop: str, *, exclude_hash: str | None = None,
                  limit: int = 20) -> list[dict[str, Any]]:
    """Earlier ok runs of a loop, read-only; [] when the database or the loop is not there."""
    if db_path is None or not Path(db_path).exists():
        return []
    try:
        with History(db_path, readonly=True) as h:
            rows = h.runs(loop, limit=limit + 1)
    except (StictionError, sqlite3.Error):
        return []
    return [r for r in rows if not exclude_hash or r.get("input_hash") != exclude_hash][-limit:]


def _when(row: Mapping[str, Any]) -> str:
    return str(row.get("data_end") or row.get("run_at") or "")


def degradation(rows: Sequence[Mapping[str, Any]], *, runs: int = DEGRADE_RUNS,
                step_pct: float = DEGRADE_STEP_PCT, total_pct: float = DEGRADE_TOTAL_PCT) -> str | None:
    """A warning when S grew record over record (rows oldest first), else None.

    The last ``runs`` runs that sized a stiction (a stored verdict of stiction; rows stored
    before verdicts were kept count too) must each raise S by at least ``step_pct`` and by at least
    ``total_pct`` in all (% of valve span; `size_pct`). A run that said no stiction has no size to grow from:
    its fitted band is the noise's, and the history does not show it either (`shown_run`). When
    the latest run that stored a verdict said no stiction there is no warning: after a repair the
    valve is not degrading, and a report that says "no stiction" should not say "degrading".
    """
    said = [r for r in rows if r.get("stiction") is not None]
    if said and not bool(said[-1]["stiction"]):
        return None
    # in % of span, whatever units each run's OP was logged in (a tag map added later changes them)
    s = [(_when(r), size_pct(r), run_units(r)) for r in rows
         if r.get("S_pct") is not None and (r.get("stiction") is None or bool(r["stiction"]))]
    if len(s) < runs:
        return None
    last = s[-runs:]
    vals = [float(v) for _, v, _ in last]
    steps = [b - a for a, b in zip(vals, vals[1:])]
    if all(d >= step_pct for d in steps) and vals[-1] - vals[0] >= total_pct:
        if any(u == "OP units" for _, _, u in last):
            grew = f"from {vals[0]:.2f} to {vals[-1]:.2f} ({units_in_words('OP units')})"
        else:
            grew = f"from {vals[0]:.2f} % to {vals[-1]:.2f} % of span"
        return (f"S grew over the last {runs} runs, {grew} "
                f"({str(last[0][0])[:10]} to {str(last[-1][0])[:10]}): the valve is getting worse; "
                "plan maintenance.")
    return None


def sticky_runs(rows: Sequence[Mapping[str, Any]], *, runs: int = PERSIST_RUNS) -> tuple[int, int, float | None] | None:
    """(runs that said stiction, runs counted, their median probability) over the loop's last
    ``runs`` runs that stored a verdict (rows oldest first); None with fewer than two.

    One window can hold too little stick-slip for the fit to tell (docs/verdict.md, Limits): a
    valve called sticky on most of its windows is a firmer finding than one window's probability.
    """
    seen = [r for r in rows if r.get("stiction") is not None][-runs:]
    if len(seen) < 2:
        return None
    ps = [float(r["stiction_probability"]) for r in seen if r.get("stiction_probability") is not None]
    return sum(bool(r["stiction"]) for r in seen), len(seen), statistics.median(ps) if ps else None


def persistence(rows: Sequence[Mapping[str, Any]], *, runs: int = PERSIST_RUNS) -> str | None:
    """`sticky_runs` in words: "stiction in 5 of the last 7 runs, median probability 84 %"."""
    got = sticky_runs(rows, runs=runs)
    if got is None:
        return None
    k, m, med = got
    return f"stiction in {k} of the last {m} runs" + ("" if med is None else f", median probability {percent(med)}")


#: A run's columns that size the stiction it found (`shown_run` leaves them out of runs without).
SIZE_COLUMNS = ("S_pct", "S_lo", "S_hi", "J_pct", "J_lo", "J_hi")


def said_no_stiction(row: Mapping[str, Any]) -> bool:
    """The stored run's verdict was no stiction. False for rows of releases that stored no verdict
    (``stiction`` None): they are read by their S alone."""
    return row.get("stiction") is not None and not row["stiction"]


def shown_run(row: Mapping[str, Any]) -> dict[str, Any]:
    """A stored run as `stiction history` shows it: S, J and their intervals only when the run said
    stiction (docs/verdict.md), as the summary gives them. The database keeps them as stored;
    rows of releases that stored no verdict (``stiction`` None) show them as before."""
    out = dict(row)
    if said_no_stiction(out):
        out.update(dict.fromkeys(SIZE_COLUMNS))
    return out


def format_trend(loop: str, rows: Sequence[Mapping[str, Any]], *, limit: int | None = None) -> str:
    """The trend table `stiction history LOOP` prints: one line per run, by the end of its record.

    ``limit`` shows only the last runs; the persistence and the degradation are still judged on
    all of ``rows`` (the loop's last 7 and 3 runs), as the reports and the summary judge them."""
    if not rows:
        return f"{loop}: no runs in the history\n"
    shown = list(rows)[-limit:] if limit else list(rows)
    head = f"{loop}: {len(rows)} run(s)" + (f", the last {len(shown)} shown" if len(shown) < len(rows) else "")
    units = [run_units(r) for r in shown]
    # S and J in each run's own units; the heads say % only when every run shown is in %
    plain_pct = all(u == "% of span" for u in units)
    s_head, j_head = ("S %", "J %") if plain_pct else ("S", "J")
    cells = []
    for r, u in zip(map(shown_run, shown), units):
        spec = f".{sj_decimals(u)}f"
        iv = ("-" if r.get("S_lo") is None or r.get("S_hi") is None
              else f"[{r['S_lo']:{spec}}, {r['S_hi']:{spec}}]")
        S = "-" if r.get("S_pct") is None else f"{r['S_pct']:{spec}}"
        J = "-" if r.get("J_pct") is None else f"{r['J_pct']:{spec}}"
        conf = percent(r.get("confidence"))   # as the reports word it: a rounded "100%" reads as a certainty
        sev = "-" if r.get("severity") is None else f"{r['severity']:.1f}"     # as the summary gives it
        end = str(r.get("data_end") or "-")[:19]
        p = percent(r.get("stiction_probability"))
        cells.append((end, p, S, iv, J, str(r.get("class") or "-"), conf, sev, str(r.get("run_at"))[:19], u))
    ws = max([6] + [len(c[2]) for c in cells] + [len(c[4]) for c in cells])
    wi = max([15] + [len(c[3]) for c in cells])
    lines = [head,
             f"{'record end (UTC)':<20} {'P(st.)':>6} {s_head:>{ws}} {'S interval':>{wi}} {j_head:>{ws}} "
             f"{'class':<12} {'conf':>6} {'sev':>5}  {'run (UTC)':<20}" + ("" if plain_pct else " S, J units")]
    for end, p, S, iv, J, cls, conf, sev, run_at, u in cells:
        lines.append(f"{end:<20} {p:>6} {S:>{ws}} {iv:>{wi}} {J:>{ws}} {cls:<12} {conf:>6} {sev:>5}  {run_at:<20}"
                     + ("" if plain_pct else f" {u}"))
    held = persistence(rows)
    if held:
        lines.append(f"Verdict: {held}")
    warn = degradation(rows)
    if warn:
        lines.append(f"WARNING: {warn}")
    return "\n".join(ln.rstrip() for ln in lines) + "\n"
