"""Connectors: historian exports, DataFrames and Modbus/TCP devices into `diagnose.record.LoopRecord`s.

`read_loops` (also reachable as `read_records`, which takes the same options as a mapping) is the
one entry point for files: it detects the layout (see `connectors.layouts`; pandas parses the
rows), finds the loops (naming rule in `connectors.columns`, or a tag map, or explicit column
names), puts every loop on a uniform time grid (`connectors.timebase`), splits it at long gaps,
keeps the newest ``max_samples`` samples and attaches data-quality findings
(`diagnose.quality.assess`). `read_frame` does the same for a pandas DataFrame. Users reach both
through `diagnose.read_loops` (docs/api.md). Modbus polling lives in `connectors.modbus` (imported
on demand: it pulls in pymodbus).
"""

from __future__ import annotations

import os
import re
from typing import IO, Any, Mapping

from diagnose.errors import ConnectorError, StictionError
from diagnose.record import LoopRecord

FILE_SUFFIXES = (".csv", ".txt", ".tsv", ".dat", ".prn")
OPTIONS = ("op", "pv", "sp", "mv", "mode", "time", "ts", "ts_s", "name", "fmt", "format", "tags", "tz", "dst",
           "dayfirst", "loop", "max_gap_s", "min_samples", "max_samples", "progress")


def list_sources(path: str | os.PathLike) -> list[str]:
    """The export files of a folder (sorted; hidden files skipped), or ``[path]`` for a file."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        return [path]
    out = []
    for entry in sorted(os.listdir(path)):
        full = os.path.join(path, entry)
        if entry.startswith(".") or not os.path.isfile(full):
            continue
        if entry.lower().endswith(FILE_SUFFIXES):
            out.append(full)
    return out


def read_loops(source: str | os.PathLike | IO[Any], *, tags: Any = None, tz: str | None = None,
               dst: str | None = None, dayfirst: bool | None = None, op: str | None = None,
               pv: str | None = None, sp: str | None = None, mv: str | None = None, mode: str | None = None,
               time: str | None = None, ts: str | None = None, ts_s: float | None = None, name: str | None = None,
               fmt: str | None = None,
               loop: str | None = None, max_gap_s: float | None = None, min_samples: int | None = None,
               max_samples: int | None = None, progress: Any = None) -> list[LoopRecord]:
    """Read every loop in a historian export (file, folder of files, or file object) into records.

    Parameters
    ----------
    source : path, folder or file object (text or binary)
    tags : path, parsed TOML dict or `connectors.tagmap.TagMap`, optional
        Tag map (TOML): loops, roles, ranges for scaling OP/MV to % of span.
    tz : str, optional
        Time zone of naive timestamps (IANA name or ``+hh:mm``; default UTC).
    dst : {"infer", "earliest", "latest", "raise"}
        Policy for ambiguous/missing local times at DST changes (default ``infer``).
    dayfirst : bool, optional
        Dates such as ``05/03/2026`` are day first (True: 5 March) or month first (False: 3 May).
        Default: decided from the dates (a field above 12, else the reading whose dates lie closer
        together, else the custom of the separator, with a ``date_order`` warning). The files of
        a folder share one order where a file alone cannot tell it (`date_orders`).
    op, pv, sp, mv, mode : str, optional
        Column (tag) names that override the naming rule; OP/PV given -> one loop.
    time : str, optional
        Name of the time column (default: found by its name or content). ``ts`` is an older
        spelling of the same option.
    ts_s : float, optional
        Sample period in seconds (default: median spacing of the timestamps; the DCS export's own).
    name : str, optional
        Loop name when the file holds one loop.
    fmt : {"auto", "wide", "long", "ragged", "influx", "dcs"}, optional
        Layout override (default auto-detect).
    loop : str, optional
        Keep only this loop (by name).
    max_gap_s : float, optional
        Longest gap filled by linear interpolation (default 10 sample periods); longer gaps split
        the record into segments.
    min_samples : int, optional
        Shortest usable segment (default 20 samples).
    max_samples : int, optional
        Samples kept per loop for diagnosis: the newest ``max_samples`` (default 100 000; 0 keeps
        all). A loop cut to them carries a ``window`` finding.
    progress : bool or callable, optional
        Progress lines while reading: a callable taking one line of text, True (stderr), False
        (none). Default: on stderr for files of 32 MB or more.

    Returns
    -------
    list of LoopRecord
        One per loop per contiguous segment (``meta["segment"]``, ``meta["n_segments"]``), with the
        connector's and `diagnose.quality.assess`'s findings and ``meta["quality_checked"] = True``.

    Raises
    ------
    diagnose.errors.ConnectorError
        One line naming the file (line, column) and the problem.
    """
    options = {k: v for k, v in dict(tags=tags, tz=tz, dst=dst, dayfirst=dayfirst, op=op, pv=pv, sp=sp, mv=mv,
                                     mode=mode, time=time, ts=ts, ts_s=ts_s, name=name, fmt=fmt, loop=loop,
                                     max_gap_s=max_gap_s, min_samples=min_samples, max_samples=max_samples,
                                     progress=progress).items() if v is not None}
    return read_records(source, **options)


def _reading_options(options: dict[str, Any]) -> tuple[dict[str, Any], Any, Any]:
    """The options as the readers take them, the tag map (or None) and the progress option: a tag
    map's reading options fill what was not given, old spellings become new ones."""
    from .tagmap import TagMap, load_tagmap, parse_tagmap

    unknown = set(options) - set(OPTIONS)
    if unknown:
        raise ConnectorError(f"unknown read options {sorted(unknown)}; allowed: {', '.join(OPTIONS)}")
    options = {k: v for k, v in options.items() if v is not None}
    progress = options.pop("progress", None)
    tags = options.pop("tags", None)
    tagmap = None
    if tags is not None:
        if isinstance(tags, TagMap):
            tagmap = tags
        elif isinstance(tags, dict):
            tagmap = parse_tagmap(tags)
        else:
            tagmap = load_tagmap(tags)
        for k, v in tagmap.options.items():
            options.setdefault("fmt" if k == "format" else k, v)
    if "format" in options:
        options.setdefault("fmt", options.pop("format"))
    if "time" in options:
        options.setdefault("ts", options.pop("time"))
    return options, tagmap, progress


def with_tag_map_options(options: Mapping[str, Any], tags: Any) -> dict[str, Any]:
    """``options`` with the tag map ``tags``'s reading options (date order, time zone, format...)
    filling what was not given, as `read_records` applies them where the map names a loop: for a
    file read by the naming rule because the map names no loop in it."""
    out, _, progress = _reading_options({**options, "tags": tags})
    return out if progress is None else {**out, "progress": progress}


def _shared_orders(tables: list[Any]) -> list[bool | None]:
    """For each table of one folder: the date order the folder's files say together, where the
    file alone cannot say it (every day and month 12 or less); None where the file decides for
    itself, has no such dates, or the files together cannot tell either (each is then read, and
    warned about, as alone)."""
    from .timebase import alike_both_ways, shared_date_order

    dates = [(t.meta.get("dates") or {}).get("dates") or [] for t in tables]
    # files of one export share their layout and time format: a US export (month first, AM/PM)
    # beside a UK one (day first, 24 h) in the same folder must not lend it its order
    groups: dict[tuple, list[int]] = {}
    for k, t in enumerate(tables):
        groups.setdefault(_export_signature(t), []).append(k)
    out: list[bool | None] = [None] * len(tables)
    for idx in groups.values():
        order = shared_date_order(d for k in idx for d in dates[k])
        for k in idx:
            out[k] = order if order is not None and alike_both_ways(dates[k]) else None
    return out


def _export_signature(table: Any) -> tuple:
    """What the files of one export have in common: layout, separators, the time column and its
    format with day and month taken as one field (their order is what is being decided)."""
    m = table.meta
    fmt = str(m.get("time_format") or "").replace("%d", "%D").replace("%m", "%D")
    return (m.get("format"), m.get("delimiter"), m.get("decimal"), fmt, (m.get("dates") or {}).get("column"))


#: Bytes of a file `date_orders` looks at before it reads the whole file.
_DATE_SNIFF_BYTES = 1 << 16
#: A date whose first two fields could be day or month (05/03/2026, 5.3.26, 05-03-2026).
_DAY_MONTH_DATE = re.compile(rb"(?<![0-9])[0-9]{1,2}[/.-][0-9]{1,2}[/.-][0-9]{2,4}(?![0-9])")


def _may_hold_day_month_dates(src: Any) -> bool:
    """Whether a file's head shows a date like ``05/03/2026`` (or cannot be sniffed cheaply: a
    file object, or text that is not ASCII-compatible, such as UTF-16). A nightly batch over a
    folder of ISO-stamped exports then reads each file once, not twice."""
    if hasattr(src, "read"):
        return True
    try:
        with open(os.fspath(src), "rb") as fh:
            head = fh.read(_DATE_SNIFF_BYTES)
    except OSError:
        return True
    return b"\x00" in head or _DAY_MONTH_DATE.search(head) is not None


def date_orders(sources: list[Any], **options: Any) -> list[bool | None]:
    """The date order each of one export's files (a folder of one-day files) is to be read in.

    Returns, per source, True (day first) or False (month first) where the file alone cannot say
    (every day and month 12 or less: ``05/03/2026`` all day) and the files together can; None
    where the file decides for itself, could not be read, or the files together cannot tell
    either. `read_records` does this for a folder; the batch, which reads each file on its own,
    asks here first. A ``dayfirst`` option (or a tag map's) decides alone: all None.
    """
    from .layouts import parse
    from .textio import open_source

    options, _, _ = _reading_options(options)
    if options.get("dayfirst") is not None:
        return [None] * len(sources)
    tables = []
    for src in sources:
        if not _may_hold_day_month_dates(src):
            tables.append(None)   # ISO or numeric times: nothing to share, and no second full read
            continue
        try:
            tables.append(parse(open_source(src, False), options))
        except (StictionError, OSError):
            tables.append(None)   # the reading of the file itself says what is wrong with it
    read = [t for t in tables if t is not None]
    orders = iter(_shared_orders(read))
    return [None if t is None else next(orders) for t in tables]


def read_records(source: str | os.PathLike | IO[Any], **options: Any) -> list[LoopRecord]:
    """`read_loops` with its options as keyword arguments from a mapping (``**options``).

    Unknown option names are a `ConnectorError` (the command line and the batch pass their
    options through here). The files of a folder share one date order (`date_orders`).
    """
    from .layouts import parse
    from .records import build_records, merge_specs, specs_from_table
    from .textio import open_source

    options, tagmap, progress = _reading_options(options)
    if hasattr(source, "read"):
        sources: list[Any] = [source]
        folder = False
    else:
        path = os.fspath(source)
        if not os.path.exists(path):
            raise ConnectorError("file not found", path=path)
        folder = os.path.isdir(path)
        sources = list_sources(path)
        if folder and not sources:
            raise ConnectorError(f"folder has no export files ({', '.join(FILE_SUFFIXES)})", path=path)
    skipped: list[tuple[str, str]] = []

    def skip(src: Any, exc: BaseException) -> None:
        if not folder:
            raise exc
        # one bad export (empty, cut off, a stray CSV) must not hide the loop the others hold
        text = " ".join(str(exc).split()) or type(exc).__name__
        skipped.append((src, text if text.startswith(src) else f"{src}: {text}"))

    read = []
    for src in sources:
        try:
            opened = open_source(src, progress)
            read.append((src, opened, parse(opened, options)))
        except (StictionError, OSError) as exc:
            skip(src, exc)
    if folder and options.get("dayfirst") is None:
        # one export's files share one date order: a file of 05/03/2026 alone cannot tell it
        for k, order in enumerate(_shared_orders([t for _, _, t in read])):
            src, opened, table = read[k]
            if order is None:
                continue
            if table.meta["dates"]["dayfirst"] != order:
                opened = open_source(src, progress)
                read[k] = (src, opened, parse(opened, dict(options, dayfirst=order)))
            else:
                table.meta.pop("date_order_guessed", None)   # read as the folder says: no guess
    specs = []
    reporters = {}
    for src, opened, table in read:
        try:
            found = specs_from_table(table, options, tagmap)
        except (StictionError, OSError) as exc:
            skip(src, exc)
            continue
        reporters[table.label] = opened.progress
        if not found and tagmap is not None and not folder:
            wanted = ", ".join(f"{lm.roles['op'].tag}/{lm.roles['pv'].tag}" for lm in list(tagmap.loops.values())[:5])
            cols = ", ".join([s.name for s in table.series][:12])
            raise ConnectorError(f"none of the tag map's loops ({wanted}) has its OP and PV tags in the file "
                                 f"(columns: {cols})", path=table.label)
        specs.extend(found)
    if folder:   # in the folder's order, whichever stage a file failed at
        skipped.sort(key=lambda item: sources.index(item[0]))
    # where the loop wanted may sit in a file that could not be read, the error says so
    unread = (f"; {len(skipped)} of its files could not be read (the first: {skipped[0][1]})"
              if skipped else "")
    if not specs and skipped and len(skipped) == len(sources):
        raise ConnectorError(f"none of its {len(sources)} export files could be read (the first: {skipped[0][1]})",
                             path=os.fspath(source))
    if not specs:
        raise ConnectorError("no loop of the tag map was found in any file" + unread, path=os.fspath(source)
                             if not hasattr(source, "read") else None)
    specs = merge_specs(specs)
    if options.get("loop"):
        want = str(options["loop"])
        sel = [s for s in specs if s.name == want or s.name.lower() == want.lower()]
        if not sel:
            raise ConnectorError(f"no loop named {want!r} (loops: {', '.join(s.name for s in specs)}){unread}",
                                 path=None if hasattr(source, "read") else os.fspath(source))
        specs = sel
    records: list[LoopRecord] = []
    for spec in specs:
        reporter = reporters.get(spec.table.label) if spec.table else None
        records.extend(build_records(spec, dict(options, _progress=reporter)))
    if skipped:
        from diagnose.record import Finding

        # info, not a warning: the loops read are whole as read, and the commands print each
        # skipped file on stderr (`file_skipped`)
        notes = [Finding("file_skipped", f"skipped {text}", "info", {"path": src}) for src, text in skipped]
        records = [r.with_findings(*notes) for r in records]
    return records


def read_frame(df: Any, **options: Any) -> list[LoopRecord]:
    """Every loop in a pandas DataFrame as records, one per loop per contiguous segment, read the
    way `read_loops` reads a file (options as there, without ``tags``, ``fmt`` and ``progress``;
    see `connectors.frame`). Raises `diagnose.errors.DataError`."""
    from .frame import records_from_frame

    return records_from_frame(df, **options)
