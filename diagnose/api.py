"""The Python front door: `identify`, `explain` and `read_loops` on a file, a DataFrame or a record.

These are the functions ``import diagnose`` exports, and what the ``stiction identify`` and
``stiction explain`` commands run: a result from Python is the one the command prints for the same
input and options. They sit in the shell layer (they read files through `connectors`); the core
functions they call take a `LoopRecord` (`diagnose.identification.identify`,
`diagnose.physics.explain`).

Options mean the same everywhere (docs/api.md has the table):

* ``op``, ``pv``, ``sp``, ``mv``: the columns (tags) of controller output, process variable,
  setpoint and valve stem position (``--op`` ... on the command line); by default the naming rule
  finds them (docs/connectors.md), the stem position included;
* ``time``: the time column (``--time``); ``ts_s``: the sample period in seconds (``--ts-s``);
* ``tz``: the time zone of naive times (``--tz``), ``dst``: the policy at clock changes (``--dst``);
* ``dayfirst``: dates such as ``05/03/2026`` are day first (True, ``--dayfirst``) or month first
  (False, ``--monthfirst``); by default the dates decide, and a ``date_order`` warning says when
  they cannot;
* ``loop``: which loop of a file or frame that holds several (``--loop``);
* ``tags``: a tag map (``--tags``); ``format``: the file layout (``--format``);
* ``max_samples``: samples kept per loop, the newest (``--max-samples``; 0 keeps all).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from typing import IO, TYPE_CHECKING, Any, Callable, Mapping, Sequence

from .errors import DataError, StictionError
from .notes import Note
from .objective import MIN_SAMPLES
from .record import LoopRecord

if TYPE_CHECKING:
    import pandas as pd

    from .identification import Identification
    from .physics import Explanation

#: The read options every front-door function and file command takes.
READ_OPTIONS = ("op", "pv", "sp", "mv", "time", "ts_s", "tz", "dst", "dayfirst", "loop", "tags", "format",
                "max_samples")
_FRAME_ONLY_NOT = ("tags", "format")


def _is_frame(data: Any) -> bool:
    mod = type(data).__module__ or ""
    if not mod.startswith("pandas"):
        return False
    import pandas as pd

    return isinstance(data, pd.DataFrame)


def _check_data(data: Any) -> None:
    if isinstance(data, (str, os.PathLike, LoopRecord)) or _is_frame(data) or callable(getattr(data, "read", None)):
        return
    # an array's repr runs to many lines; its type says enough
    shown = repr(data) if data is None or isinstance(data, numbers.Number) else \
        f"<{type(data).__module__}.{type(data).__qualname__}>"
    hint = ""
    if hasattr(data, "__len__") and not isinstance(data, (bytes, bytearray)):
        # arrays, lists, a Series, a dict of columns: the roles need names and the samples a period
        hint = " (for arrays: pandas.DataFrame({'OP': op, 'PV': pv}) with ts_s=SECONDS)"
    raise DataError(f"data={shown}: give a path (file or folder), a file object, a pandas DataFrame or a "
                    f"LoopRecord{hint}")


def _positive(v: Any) -> bool:
    """A finite number above 0 (not a bool)."""
    return not isinstance(v, bool) and isinstance(v, numbers.Real) and math.isfinite(v) and v > 0


def _whole(v: Any, least: int) -> bool:
    """A whole number of at least ``least`` (not a bool)."""
    return not isinstance(v, bool) and isinstance(v, numbers.Real) and float(v).is_integer() and v >= least


def _checked(opts: dict[str, Any], key: str, ok: Callable[[Any], bool], convert: Callable[[Any], Any],
             says: str) -> None:
    """``opts[key]``, where given, converted, or a one-line `DataError`: ``key=value`` and ``says``."""
    v = opts.get(key)
    if v is None:
        return
    if not ok(v):
        raise DataError(f"{key}={v!r}{says}")
    opts[key] = convert(v)


def check_read_options(options: Mapping[str, Any], *, diagnosis: bool = False) -> dict[str, Any]:
    """The reading options with their values checked (``ts_s`` as a float, ``max_samples`` as an
    int); a bad one raises a one-line `DataError` naming the keyword and its command-line flag.

    The one check for every entry point: `read_loops` (so `identify` and `explain`), the file
    commands and `diagnose.service.batch.run_batch`. ``diagnosis``: the records are read to be
    diagnosed, so ``max_samples`` must keep at least the shortest record a diagnosis takes (a
    smaller limit would fail later, on another minimum than the one the user set).
    """
    from connectors.timebase import DST_POLICIES, zone_of

    opts = dict(options)
    # 0 or NaN would otherwise read as "not given" further down and a period be guessed
    _checked(opts, "ts_s", _positive, float,
             " (--ts-s): the sample period must be a positive number of seconds")
    n = opts.get("max_samples")
    _checked(opts, "max_samples", lambda v: _whole(v, 0), int,
             " (--max-samples): give a whole number of samples, 0 or more (0 keeps all)")
    if diagnosis and n is not None and 0 < opts["max_samples"] < MIN_SAMPLES:
        raise DataError(f"max_samples={n!r} (--max-samples): keeps fewer samples than a diagnosis needs "
                        f"({MIN_SAMPLES}); give {MIN_SAMPLES} or more, or 0 to keep every sample")
    gap = opts.get("max_gap_s")
    if gap == 0 and not isinstance(gap, bool):
        opts.pop("max_gap_s")           # 0: the reader's default, as it always meant
    _checked(opts, "max_gap_s", _positive, float,
             ": the longest gap to fill must be a positive number of seconds")
    _checked(opts, "min_samples", lambda v: _whole(v, 2), int, ": give a whole number of samples, 2 or more")
    dayfirst = opts.get("dayfirst")
    if dayfirst is not None and not isinstance(dayfirst, bool):
        raise DataError(f"dayfirst={dayfirst!r} (--dayfirst/--monthfirst): give True (day first), False "
                        "(month first) or None (decided from the dates)")
    dst = opts.get("dst")
    if dst is not None and dst not in DST_POLICIES:
        raise DataError(f"dst={dst!r} (--dst): use one of {', '.join(DST_POLICIES)}")
    tz = opts.get("tz")
    if tz is not None:
        try:
            zone_of(tz)
        except StictionError as exc:   # the reader's own words: out of range, not a zone name, ...
            raise DataError(f"tz={tz!r} (--tz): {exc}") from None
    return opts


def read_loops(data: str | os.PathLike | IO[Any] | pd.DataFrame | LoopRecord, *, op: str | None = None,
               pv: str | None = None, sp: str | None = None, mv: str | None = None, time: str | None = None,
               ts_s: float | None = None, tz: str | None = None, dst: str | None = None,
               dayfirst: bool | None = None, loop: str | None = None, tags: Any = None, format: str | None = None,
               max_samples: int | None = None, max_gap_s: float | None = None,
               min_samples: int | None = None, progress: Any = None) -> list[LoopRecord]:
    """Every loop in a historian export, a folder of them, or a pandas DataFrame, as records.

    Files and frames are read the same way: the layout is detected, the naming rule (or ``op=``...,
    or a tag map) finds each loop's OP, PV, SP and MV, times are sorted and put on a uniform grid,
    short gaps are filled and long ones split a loop into segments, and data-quality findings are
    attached (docs/connectors.md).

    Parameters
    ----------
    data : path, folder, file object, pandas.DataFrame or LoopRecord
        A DataFrame's time is its `DatetimeIndex`, or a time column (``time=`` or found by name),
        or its row number times ``ts_s``. A record is returned as it is.
    op, pv, sp, mv : str, optional
        Column names (tags) of OP (% of span), PV, SP and the valve stem position MV (% of span).
    time : str, optional
        Name of the time column.
    ts_s : float, optional
        Sample period in seconds (default: the median spacing of the times).
    tz : str, optional
        Time zone of naive times (IANA name or ``+hh:mm``; default UTC).
    dst : {"infer", "earliest", "latest", "raise"}, optional
        Ambiguous or missing local times at clock changes (default ``infer``).
    dayfirst : bool, optional
        Dates such as ``05/03/2026`` are day first (True: 5 March) or month first (False: 3 May);
        by default the dates decide, and a ``date_order`` warning says when they cannot.
    loop : str, optional
        Keep only this loop.
    tags : path or mapping, optional
        Tag map (TOML) naming each loop's tags and ranges (files only).
    format : {"auto", "wide", "long", "ragged", "influx", "dcs"}, optional
        Layout override (files only).
    max_samples : int, optional
        Samples kept per loop, the newest (default 100 000; 0 keeps all).
    max_gap_s, min_samples, progress
        As in `connectors.read_loops`.

    Returns
    -------
    list of LoopRecord
        One per loop per contiguous segment.

    Raises
    ------
    DataError
        One line naming the file (line, column) or frame column and what is wrong.
    """
    _check_data(data)
    given = dict(op=op, pv=pv, sp=sp, mv=mv, time=time, ts_s=ts_s, tz=tz, dst=dst, dayfirst=dayfirst, loop=loop,
                 max_samples=max_samples, max_gap_s=max_gap_s, min_samples=min_samples)
    opts: dict[str, Any] = check_read_options({k: v for k, v in given.items() if v is not None})
    if isinstance(data, LoopRecord):
        given = sorted(k for k, v in dict(opts, tags=tags, format=format).items() if v is not None)
        if given:
            raise DataError(f"{', '.join(given)}: reading options apply to files and frames, not to a LoopRecord")
        return [data]
    if _is_frame(data):
        for key, value in (("tags", tags), ("format", format)):
            if value is not None:
                raise DataError(f"{key}= applies to files, not to a DataFrame (name the columns with op=, pv=...)")
        from connectors import read_frame

        return read_frame(data, **opts)
    import connectors

    return connectors.read_loops(data, tags=tags, fmt=format, progress=progress, **opts)


def records_named(records: Sequence[LoopRecord], loop: str) -> list[LoopRecord]:
    """The records of the loop named ``loop``, its name matched exactly: the readers keep
    ``FIC102`` and ``fic102`` as two loops, so ``--loop`` names one of them (identify, explain and
    the batch alike)."""
    return [r for r in records if r.name == loop]


def choose_record(records: Sequence[LoopRecord], loop: str | None, source: str,
                  verb: str = "identified") -> tuple[LoopRecord, tuple[Note, ...]]:
    """The record to work on: the named (or only) loop's longest segment, and notes that say so."""
    if not records:
        raise DataError(f"{source}: no loop found")
    names = list(dict.fromkeys(r.name for r in records))
    if loop is not None:
        chosen = records_named(records, loop)
        if not chosen:
            raise DataError(f"{source}: no loop named {loop!r} (loops: {', '.join(names)})")
    elif len(names) > 1:
        raise DataError(f"{source} holds {len(names)} loops ({', '.join(names)}); choose one with --loop NAME "
                        "(loop= in Python)")
    else:
        chosen = list(records)
    rec = max(chosen, key=lambda r: r.n)
    notes: tuple[Note, ...] = ()
    if len(chosen) > 1:
        notes = (Note("segments", f"the record is split into {len(chosen)} segments at gaps; "
                                  f"{verb} the longest ({rec.n} samples)"),)
    return rec, notes


def _label(data: Any) -> str:
    if isinstance(data, (str, os.PathLike)):
        return os.fspath(data)
    if _is_frame(data):
        return "the DataFrame"
    return str(getattr(data, "name", None) or "the input")


def load(data: Any, verb: str = "identified", **options: Any) -> tuple[LoopRecord, tuple[Note, ...]]:
    """The one record a front-door function works on (``loop=`` picks among several loops; the
    longest segment is taken) and the notes that say what was chosen. Options as `read_loops`."""
    check_read_options({k: v for k, v in options.items() if k == "max_samples" and v is not None},
                       diagnosis=True)
    # a stretch shorter than a diagnosis takes is no candidate: the reader says so with the
    # minimum that applies, rather than a shorter one that only leads to the next error
    if not isinstance(data, LoopRecord):
        options = dict(options, min_samples=options.get("min_samples") or MIN_SAMPLES)
    records = read_loops(data, **options)
    return choose_record(records, options.get("loop"), _label(data), verb)


def identify(data: str | os.PathLike | pd.DataFrame | LoopRecord, *, op: str | None = None,
             pv: str | None = None, sp: str | None = None, mv: str | None = None, ts_s: float | None = None,
             loop: str | None = None, tz: str | None = None, time: str | None = None, dst: str | None = None,
             dayfirst: bool | None = None, tags: Any = None, format: str | None = None,
             max_samples: int | None = None, narx: bool = True) -> Identification:
    """Identify stiction in one loop: verdict, S and J (% of valve span), class, evidence, process.

    The same as ``stiction identify FILE``: the record is read as the command reads it (the stem
    position MV is used when the data have one), identified by `diagnose.identification.identify`,
    and the NARX-SP bank model nearest to the identified (S, J) is selected. ``result.to_dict()``
    is the JSON object ``stiction identify --json`` prints.

    Parameters
    ----------
    data : path, pandas.DataFrame or LoopRecord
        A historian export, a DataFrame (a `DatetimeIndex`, a time column, or evenly spaced rows
        with ``ts_s``), or a record. A file or frame with several loops needs ``loop``; of a loop
        split at long gaps the longest segment is identified (a ``segments`` warning says so).
    op, pv, sp, mv, ts_s, loop, tz, time, dst, dayfirst, tags, format, max_samples
        Reading options, as in `read_loops` (they do not apply to a LoopRecord).
    narx : bool
        Select the NARX-SP bank model (``result.narx``); False leaves it None.

    Returns
    -------
    Identification

    Raises
    ------
    DataError
        The data cannot be read or judged (too short, OP constant...).
    """
    from .identification import identify as identify_record

    rec, notes = load(data, "identified", op=op, pv=pv, sp=sp, mv=mv, ts_s=ts_s, loop=loop, tz=tz, time=time,
                      dst=dst, dayfirst=dayfirst, tags=tags, format=format, max_samples=max_samples)
    ident = identify_record(rec)
    warnings = notes + ident.warnings
    selection = None
    if narx:
        from .service.pipeline import select_narx

        selection, note = select_narx(ident)
        if note is not None:
            warnings = warnings + (note,)
    source = ident.source
    if source is None and isinstance(data, (str, os.PathLike)):
        source = os.fspath(data)
    return dataclasses.replace(ident, warnings=warnings, narx=selection, source=source)


def explain(data: str | os.PathLike | pd.DataFrame | LoopRecord, *, op: str | None = None,
            pv: str | None = None, sp: str | None = None, mv: str | None = None, ts_s: float | None = None,
            loop: str | None = None, tz: str | None = None, time: str | None = None, dst: str | None = None,
            dayfirst: bool | None = None, tags: Any = None, format: str | None = None,
            max_samples: int | None = None, target: str = "auto", train_fraction: float = 0.65,
            hypotheses: Sequence[str] | None = None, min_reduction: float = 0.10) -> Explanation:
    """Locate where the identified model and the record disagree and name the missing physics.

    The same as ``stiction explain FILE``: the record is read as `identify` reads it and passed to
    `diagnose.physics.explain` (docs/missing-physics.md). It takes 3-40 s per loop.

    Parameters
    ----------
    data, op, pv, sp, mv, ts_s, loop, tz, time, dst, dayfirst, tags, format, max_samples
        As in `identify`.
    target : {"auto", "pv", "mv"}
        ``auto``: OP -> PV, plus OP -> MV for valve-side effects when MV is recorded; ``pv``: OP/PV
        only; ``mv``: the valve alone (needs MV).
    train_fraction : float
        Leading fraction of the record the fits may use; the rest is held out (0.3 to 0.9).
    hypotheses : sequence of str or str, optional
        Hypotheses to test (default: all registered, `diagnose.physics.REGISTRY`); a string is one
        name or a comma-separated list, as ``--hypotheses a,b``.
    min_reduction : float
        Smallest relative held-out RMSE reduction that names an effect (0 to 1).

    Returns
    -------
    diagnose.physics.Explanation

    Raises
    ------
    DataError
        The data cannot be read or judged, or an option is out of range (one line naming it).
    """
    from .physics import explain as explain_record

    def fraction(v: Any) -> bool:
        return not isinstance(v, bool) and isinstance(v, numbers.Real)

    if not (fraction(train_fraction) and 0.3 <= train_fraction <= 0.9):
        raise DataError(f"train_fraction={train_fraction!r} (--train-fraction): use a value between 0.3 and 0.9")
    if not (fraction(min_reduction) and 0.0 < min_reduction < 1.0):
        raise DataError(f"min_reduction={min_reduction!r} (--min-reduction): use a value between 0 and 1")
    if isinstance(hypotheses, str):
        # one name, or the command's comma-separated list: a bare string would be read letter by letter
        hypotheses = [h.strip() for h in hypotheses.split(",") if h.strip()]
    rec, notes = load(data, "explained", op=op, pv=pv, sp=sp, mv=mv, ts_s=ts_s, loop=loop, tz=tz, time=time,
                      dst=dst, dayfirst=dayfirst, tags=tags, format=format, max_samples=max_samples)
    result = explain_record(rec, target=target, train_fraction=train_fraction,
                            hypotheses=None if hypotheses is None else list(hypotheses), min_reduction=min_reduction)
    if not notes:
        return result
    current = tuple(result.warnings)
    # the explanation's warnings are Notes, or mappings (``dict(note)`` is a Note's JSON form)
    added: tuple[Any, ...] = notes
    if current and all(isinstance(w, dict) for w in current):
        added = tuple(n.to_dict() for n in notes)
    return dataclasses.replace(result, warnings=added + current)
