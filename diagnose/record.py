"""The loop record: one control loop's uniformly sampled data, as every stage sees it.

Conventions (python-control style): time along the last axis, seconds for time, OP and MV in % of
valve span, PV and SP in engineering units. Arrays are finite: connectors fill short gaps and split
a record at long ones before a record is built.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Mapping

import numpy as np

from .errors import DataError

ROLES = ("op", "pv", "sp", "mv")


@dataclass(frozen=True)
class Finding:
    """A data-quality (or other) finding that travels with a record into every result.

    Parameters
    ----------
    code : str
        Short machine-readable name, e.g. ``"gap"``, ``"compression"``, ``"quantisation"``,
        ``"op_saturation"``, ``"manual_mode"``, ``"frozen"``, ``"bad_values"``.
    message : str
        One sentence for a control engineer.
    severity : {"info", "warning", "error"}
        ``warning`` lowers confidence in a diagnosis; ``error`` means the loop cannot be diagnosed.
    data : mapping
        Numbers behind the message (counts, fractions, positions), JSON-serialisable.
    """

    code: str
    message: str
    severity: str = "info"
    data: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.severity not in ("info", "warning", "error"):
            raise ValueError(f"Finding.severity must be info, warning or error, not {self.severity!r}")

    def to_dict(self) -> dict[str, Any]:
        return {"code": self.code, "message": self.message, "severity": self.severity,
                "data": dict(self.data)}


#: A calendar date and time of day in ISO 8601 with an optional UTC offset: what every reader
#: and `to_frame` write, and what pandas and `datetime.fromisoformat` both read.
_ISO_START = re.compile(r"^\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2}(?:\.\d{1,9})?)?)?"
                        r"(?:Z|[+-]\d{2}:?\d{2})?$")


def _as_series(name: str, values: Any, n: int | None) -> np.ndarray:
    if np.iscomplexobj(values):
        raise DataError(f"{name} must be real numbers, got complex values")
    try:
        arr = np.asarray(values, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{name} must be numbers (an array or list of floats): {exc}") from None
    if arr.ndim != 1:
        raise DataError(f"{name} must be one-dimensional, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise DataError(f"{name} has {arr.shape[0]} samples but OP has {n}; all roles need the same length")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise DataError(f"{name} has {bad} non-finite values; fill or split gaps before building a record")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class LoopRecord:
    """One loop's uniformly sampled record.

    Parameters
    ----------
    name : str
        Loop name (tag), e.g. ``"FIC101"``.
    ts_s : float
        Sample period in seconds.
    op : array of float, shape (n,)
        Controller output in % of valve span.
    pv : array of float, shape (n,)
        Process variable in engineering units (``units["pv"]``).
    sp : array of float, shape (n,), optional
        Setpoint in PV units.
    mv : array of float, shape (n,), optional
        Valve stem position in % of span, where a positioner reports it.
    start : str, optional
        ISO 8601 time of the first sample (UTC offset included when known).
    units : mapping role -> str
        Engineering units per role (``"%"`` for OP and MV).
    ranges : mapping role -> (lo, hi)
        Value ranges used for scaling to % of span or for plots.
    findings : tuple of Finding
        Data-quality findings from the connector and later stages.
    source : str, optional
        Where the data came from (file path or device address).
    meta : mapping
        How the source was read (format, separator, time zone, segment index...).
    """

    name: str
    ts_s: float
    op: np.ndarray
    pv: np.ndarray
    sp: np.ndarray | None = None
    mv: np.ndarray | None = None
    start: str | None = None
    units: Mapping[str, str] = field(default_factory=dict)
    ranges: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    findings: tuple[Finding, ...] = ()
    source: str | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # a string or None would otherwise fail inside numpy with a message about ufuncs
        try:
            ts = math.nan if isinstance(self.ts_s, (bool, str, bytes)) else float(self.ts_s)
        except (TypeError, ValueError):
            ts = math.nan
        if not (math.isfinite(ts) and ts > 0):
            raise DataError(f"sample period ts_s must be a positive number of seconds, got {self.ts_s!r}")
        op = _as_series("OP", self.op, None)
        n = op.shape[0]
        object.__setattr__(self, "op", op)
        object.__setattr__(self, "pv", _as_series("PV", self.pv, n))
        for role in ("sp", "mv"):
            v = getattr(self, role)
            if v is not None:
                object.__setattr__(self, role, _as_series(role.upper(), v, n))
        findings = tuple(self.findings)
        if not all(isinstance(f, Finding) for f in findings):
            raise DataError("findings must be Finding objects (diagnose.record.Finding)")
        object.__setattr__(self, "findings", findings)
        object.__setattr__(self, "ts_s", float(self.ts_s))
        if self.name is None:
            object.__setattr__(self, "name", "LOOP")         # as from_frame names a nameless frame
        elif not isinstance(self.name, str):   # a tag that is a whole number (101) is still a name
            object.__setattr__(self, "name", str(self.name))
        if isinstance(self.start, datetime):
            # a datetime object: its ISO text (naive ones are UTC, as a naive ISO text is read)
            object.__setattr__(self, "start", self.start.isoformat().replace("+00:00", "Z"))
        if self.start is not None and not (isinstance(self.start, str) and _ISO_START.match(self.start)):
            raise DataError(f"start={self.start!r}: give the first sample's time in ISO 8601, e.g. "
                            "'2026-01-01T00:00:00Z', or None")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.op.shape[0])

    @property
    def duration_s(self) -> float:
        return self.n * self.ts_s

    @property
    def t_s(self) -> np.ndarray:
        """Time of each sample in seconds from the first."""
        return np.arange(self.n) * self.ts_s

    def replace(self, **changes: Any) -> "LoopRecord":
        """A copy with some fields changed (the record itself is immutable)."""
        return dataclasses.replace(self, **changes)

    def with_findings(self, *findings: Finding) -> "LoopRecord":
        return self.replace(findings=self.findings + tuple(findings))

    def slice(self, start: int, stop: int | None = None) -> "LoopRecord":
        """Samples ``start:stop`` as a new record (findings kept)."""
        sl = slice(start, stop)
        return self.replace(op=self.op[sl], pv=self.pv[sl],
                            sp=None if self.sp is None else self.sp[sl],
                            mv=None if self.mv is None else self.mv[sl])

    def roles(self) -> dict[str, np.ndarray]:
        """The present series by role name."""
        return {r: getattr(self, r) for r in ROLES if getattr(self, r) is not None}

    def data_hash(self) -> str:
        """A digest of the samples themselves (each series by role, the sample period and the
        start): the same record read again, from whatever file or by whatever release, has the same
        one. The history tells a record diagnosed again by it (a record without times has no start
        and end to tell it by)."""
        import hashlib

        h = hashlib.sha256(f"{float(self.ts_s)!r}|{self.start}".encode())
        for role, x in self.roles().items():
            h.update(f"|{role}|".encode())
            h.update(np.ascontiguousarray(x, dtype=np.float64).tobytes())
        return h.hexdigest()[:32]

    @classmethod
    def from_frame(cls, df: Any, *, op: str | None = None, pv: str | None = None, sp: str | None = None,
                   mv: str | None = None, ts_s: float | None = None, name: str | None = None,
                   tz: str | None = None) -> "LoopRecord":
        """One loop's record from a DataFrame that is already uniformly sampled (what `to_frame` writes).

        A strict constructor: the frame's rows are the record's samples as they are. For anything
        else (tag names such as ``FIC101.PV``, a time column, irregular times, gaps, duplicates,
        several loops) use `diagnose.read_loops` (or `diagnose.identify` directly), which reads a
        frame the way it reads a file.

        Parameters
        ----------
        df : pandas.DataFrame
            A `DatetimeIndex` with equal steps, or any index with ``ts_s`` given (evenly spaced rows).
        op, pv, sp, mv : str, optional
            Column names of controller output (% of span), process variable, setpoint and valve
            stem position (% of span); by default the columns named ``OP``, ``PV``, ``SP`` and
            ``MV`` (any case).
        ts_s : float, optional
            Sample period in seconds: required without a `DatetimeIndex`; with one it must agree
            with the index's step.
        name : str, optional
            Loop name (default ``df.attrs["name"]``, else ``"LOOP"``).
        tz : str, optional
            Time zone of a naive `DatetimeIndex` (IANA name; default UTC).

        Raises
        ------
        DataError
            No OP or PV column, missing values, an index whose steps are not equal, or no time.
        """
        import pandas as pd

        fix = "; diagnose.read_loops(df) reads such frames (gaps, time columns, tag names, several loops)"
        if not isinstance(df, pd.DataFrame):
            raise DataError(f"expected a pandas DataFrame, got {type(df).__name__}")
        if isinstance(df.columns, pd.MultiIndex):
            raise DataError("the frame has several column levels; flatten them to one name per column")
        names = {str(c).lower(): c for c in df.columns}
        cols: dict[str, Any] = {}
        for role, given in (("op", op), ("pv", pv), ("sp", sp), ("mv", mv)):
            if given is not None:
                if given not in df.columns:
                    raise DataError(f"no column named {given!r} for {role.upper()} "
                                    f"(columns: {', '.join(map(str, df.columns))})")
                cols[role] = given
            elif role in names:
                cols[role] = names[role]
        for role in ("op", "pv"):
            if role not in cols:
                raise DataError(f"no {role.upper()} column (columns: {', '.join(map(str, df.columns))}): name it "
                                f"{role.upper()} or give {role}={fix}")
        values = {}
        for role, col in cols.items():
            v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
            bad = int(np.count_nonzero(~np.isfinite(v)))
            if bad:
                raise DataError(f"column {col!r} ({role.upper()}) has {bad} missing or non-numeric values{fix}")
            values[role] = v
        start = None
        if isinstance(df.index, pd.DatetimeIndex):
            idx = df.index
            if idx.tz is None:
                try:
                    idx = idx.tz_localize(tz or "UTC", ambiguous="raise", nonexistent="raise")
                except Exception as exc:  # pytz/zoneinfo errors: an unknown zone or a DST fold
                    raise DataError(f"the frame's naive times cannot be read as local times in {tz}: "
                                    f"{exc}{fix}") from None
            ns = idx.tz_convert("UTC").as_unit("ns").asi8
            if len(ns) < 2:
                raise DataError("the frame needs at least two rows")
            step = np.diff(ns)
            period = float(np.median(step))
            if np.any(step <= 0):
                raise DataError("the frame's times are not in increasing order (newest first, unsorted or "
                                f"repeated): sort it with df.sort_index() and drop repeated times{fix}")
            if period <= 0 or np.max(np.abs(step - period)) > max(1e-6 * period, 1000.0):
                raise DataError(f"the frame's time steps are not equal (from {step.min() / 1e9:g} s to "
                                f"{step.max() / 1e9:g} s): LoopRecord.from_frame takes uniformly sampled "
                                f"frames{fix}")
            period_s = period / 1e9
            if ts_s is not None and abs(float(ts_s) - period_s) > 1e-6 * period_s:
                raise DataError(f"ts_s={ts_s:g} s disagrees with the index's step of {period_s:g} s")
            # what to_frame wrote, where the index still says it: the exact period (the index holds
            # whole nanoseconds) and the start as it was given (its UTC offset, or none known)
            given = df.attrs.get("ts_s")
            exact = isinstance(given, (int, float)) and abs(float(given) - period_s) <= 1e-6 * period_s
            ts_s = float(given) if exact else period_s
            first = pd.Timestamp(ns[0], tz="UTC").to_pydatetime(warn=False)
            start = first.isoformat().replace("+00:00", "Z")
            if "start" in df.attrs:
                was = df.attrs["start"]
                same = pd.Timestamp(was) if was else pd.Timestamp(0)
                same = same.tz_localize("UTC") if same.tz is None else same
                if same.tz_convert("UTC").as_unit("ns").value == int(ns[0]):
                    start = was
        elif ts_s is None:
            raise DataError(f"the frame has no DatetimeIndex: give the sample period ts_s= (seconds){fix}")
        attrs = df.attrs
        units = dict(attrs.get("units") or {})
        source = attrs.get("source")
        return cls(name=str(name or attrs.get("name") or "LOOP"), ts_s=float(ts_s), start=start,
                   units=units, source=None if source is None else str(source),
                   meta={"format": "dataframe", "columns": {r: str(c) for r, c in cols.items()}}, **values)

    def to_frame(self) -> Any:
        """The record as a pandas DataFrame: columns OP, PV[, SP][, MV] on a UTC `DatetimeIndex`.

        The index starts at `start` (at 1970-01-01 UTC when the start is unknown) and steps by
        ``ts_s``; ``attrs`` holds ``name``, ``ts_s``, ``start`` (as given, None when unknown),
        ``units`` and ``source``, which `from_frame` reads back where the index agrees with them.
        """
        import pandas as pd

        start = pd.Timestamp(self.start) if self.start else pd.Timestamp(0)
        start = start.tz_localize("UTC") if start.tz is None else start.tz_convert("UTC")
        index = pd.DatetimeIndex(start + pd.to_timedelta(self.t_s, unit="s"), name="time")
        data = {role.upper(): series for role, series in self.roles().items()}
        df = pd.DataFrame(data, index=index)
        df.attrs.update({"name": self.name, "ts_s": self.ts_s, "start": self.start, "units": dict(self.units),
                         "source": self.source})
        return df
