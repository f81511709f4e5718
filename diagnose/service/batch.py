"""The nightly batch: find loops in files/folders, diagnose each, write reports and a plant summary.

Flow: `discover` lists input files; each file is one task (`process_file`) run on a local process
pool (default), inline (``workers=1``) or on Dask distributed (``scheduler="local"`` for a
LocalCluster of ``workers`` processes, or a ``tcp://`` address). A task reads the file with
`connectors.read_records`, diagnoses every loop in it (`diagnose.service.pipeline.diagnose`) and
writes, per loop, into ``OUT/loops/LOOP/``: the figures (PNG), ``LOOP.md``, ``LOOP.pdf`` and last
``LOOP.json``, all atomically. The parent collects the outcomes as they finish (progress bar on
stderr), stores every result in the history database (one transaction per file), ranks the loops
and writes ``summary.{md,pdf,csv,json}``.

Report names: a loop's folder is named for its tag (``FIC101``); another input holding the same
tag gets ``TAG__FILE`` (its file name), and the name is kept in ``OUT/.stiction/names/``, so two
exports of one tag never overwrite each other and every later run and resume finds the same names.
The history database files every result under the tag, so exports of one loop make one history.

Files: folders are searched for the historian text exports the connectors read
(`connectors.FILE_SUFFIXES`); any other file found there is listed as skipped in the summary. A
tag map applies to the files where it names a loop; the others are read by the naming rule.

Workers die with the batch: a worker process that finds the batch gone (killed, even by
``kill -9``) stops at once instead of finishing its file.

Resume: a loop is skipped when its ``LOOP.json`` already holds the same input hash (file content +
read options + loop + pipeline options) and tool version; a whole file is skipped without being
read when its state file under ``OUT/.stiction/`` says all its loops are done. A killed job re-run
on the same inputs therefore redoes only what was not finished. A bad file or a failing loop becomes
a ``failed`` row in the summary and the batch goes on.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import re
import sys
import time
import traceback
from concurrent.futures import Future
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping, Sequence

from connectors import FILE_SUFFIXES as INPUT_SUFFIXES
from connectors.historian import atomic_write

from ..errors import DataError, StictionError
from ..parallel import cores_per_worker, usable_cores
from .report import SUMMARY_COLUMNS, tally

if TYPE_CHECKING:
    from .pipeline import Diagnosis

STATE_DIR = ".stiction"


@dataclass(frozen=True)
class BatchConfig:
    """What every task needs (picklable: it travels to worker processes).

    Parameters
    ----------
    out_dir : str
        Output folder.
    read_options : mapping
        Passed to `connectors.read_records` (column names, ``ts_s``, ``tz``...).
    tags : str, optional
        Tag-map TOML file for `connectors.read_records`.
    explain : bool or "auto"
        Run the missing-physics stage (``"auto"``: only where the fitted model leaves a mismatch).
    narx : bool
        Select and free-run the NARX-SP model.
    pdf : bool
        Write ``LOOP.pdf`` too.
    db : str, optional
        History database, read by workers for each loop's earlier runs (degradation warning).
    threads : int, optional
        Threads each loop's diagnosis may use (None: the cores the process may use). `run_batch`
        gives each worker its share of the cores; the results do not depend on it.
    """

    out_dir: str
    read_options: Mapping[str, Any] = field(default_factory=dict)
    tags: str | None = None
    explain: bool | str = False
    narx: bool = True
    pdf: bool = True
    db: str | None = None
    threads: int | None = None

    def options_key(self) -> str:
        """What the options make of a file's outputs (a file done with another key is done again)."""
        return json.dumps({"result": self.result_key(), "pdf": self.pdf}, sort_keys=True)

    def result_key(self) -> str:
        """The part of a loop's input hash that the options make: what changes the result. Whether
        PDFs are written does not, so a run with ``--no-pdf`` after one with PDFs stores no second
        history row for the same record."""
        from .pipeline import tool_version

        opts = {"read": dict(sorted(self.read_options.items())), "tags": _file_digest(self.tags),
                "explain": self.explain, "narx": self.narx, "version": tool_version()}
        return json.dumps(opts, sort_keys=True, default=str)


# ----------------------------------------------------------------------------------------------
# discovery and hashing


def discover(inputs: Iterable[str | os.PathLike], *, exclude: Iterable[str | os.PathLike] = (),
             skipped: list[dict[str, Any]] | None = None) -> tuple[list[Path], list[dict[str, Any]]]:
    """Input files (folders searched recursively for `INPUT_SUFFIXES`) and missing inputs.

    Hidden files/folders, anything under ``exclude`` (the output folder) and the output folders of
    earlier batches (a ``summary.json`` beside a ``loops`` folder) are left out. Returns
    the files in a stable order and one failure row per input path that does not exist. Other
    files found in the folders are appended to ``skipped`` (``{"path", "reason"}``) when given: a
    batch reports them rather than passing over them in silence.
    """
    excl = [Path(e).resolve() for e in exclude]
    files: list[Path] = []
    missing: list[dict[str, Any]] = []
    seen: set[Path] = set()

    def add(p: Path) -> None:
        rp = p.resolve()
        if rp in seen or any(rp == e or e in rp.parents for e in excl):
            return
        seen.add(rp)
        files.append(p)

    def unreadable(exc: OSError) -> None:
        # os.walk skips a folder it cannot list without a word; a nightly job must say so
        where = exc.filename or "?"
        if not any(Path(where).resolve() == e or e in Path(where).resolve().parents for e in excl):
            missing.append(failure_row(safe_name(Path(where).name), str(where),
                                       f"{where}: cannot read the folder: {exc.strerror or exc}", "input"))

    def earlier_output(folder: Path) -> bool:
        # another run's --out folder inside the inputs: its summary.csv is no historian export
        return (folder / "summary.json").is_file() and (folder / "loops").is_dir()

    for item in inputs:
        p = Path(item)
        if p.is_dir():
            for root, dirs, names in os.walk(p, onerror=unreadable):
                kept = []
                for d in sorted(d for d in dirs if not d.startswith(".")):
                    if earlier_output(Path(root) / d):
                        if skipped is not None:
                            skipped.append({"path": str(Path(root) / d),
                                            "reason": "the output folder of an earlier stiction batch"})
                    else:
                        kept.append(d)
                dirs[:] = kept
                if any(Path(root).resolve() == e or e in Path(root).resolve().parents for e in excl):
                    continue
                for name in sorted(names):
                    if name.startswith("."):
                        continue
                    if name.lower().endswith(INPUT_SUFFIXES):
                        add(Path(root) / name)
                    elif skipped is not None:
                        skipped.append({"path": str(Path(root) / name),
                                        "reason": "not a historian text export (" + ", ".join(INPUT_SUFFIXES) + ")"})
        elif p.is_file():
            add(p)
        else:
            missing.append(failure_row(str(p), str(p), f"{p}: no such file or folder", "input"))
    return files, missing


def shown_path(path: str | os.PathLike, inputs: Iterable[str | os.PathLike]) -> str:
    """A file as the summary names it: its path from the folder that holds the input it was found
    under (``copy2/FIC103.csv`` for input ``copy2/``), so that loops of files that share a name
    (``FIC103``, ``FIC103__FIC103``) can be told apart, without the long absolute path."""
    full = os.path.abspath(path)
    for item in inputs:
        top = os.path.abspath(item)
        if full == top or full.startswith(top.rstrip(os.sep) + os.sep):
            return Path(os.path.relpath(full, os.path.dirname(top) or top)).as_posix()
    return Path(path).name


def _file_digest(path: str | os.PathLike | None) -> str | None:
    if path is None:
        return None
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def input_hash(file_digest: str, options_key: str, loop: str = "", segment: Any = None) -> str:
    """The hash a loop's result is filed under: file content, options, tool version, loop."""
    h = hashlib.sha256()
    for part in (file_digest, options_key, loop, str(segment)):
        h.update(part.encode("utf-8"))
        h.update(b"\0")
    return h.hexdigest()[:32]


# letters and digits of any script are kept: tags such as ``Ventil_ü`` and ``Ventil_ä`` must not
# both become ``Ventil`` and share a folder and a history
_SAFE = re.compile(r"[^\w.-]+")


def safe_name(text: str) -> str:
    """A file-system-safe loop id (``FIC 101/A`` -> ``FIC_101_A``; ``Ventil_ü`` stays as it is)."""
    s = _SAFE.sub("_", str(text)).strip("._") or "loop"
    return s[:100]


def _one_line(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    text = msg[0] if msg else ""
    if isinstance(exc, StictionError):
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _read_error(path: Path, exc: OSError) -> str:
    """One line for a file the batch cannot open, in the readers' words (``FILE: cannot read: ...``)."""
    return f"{path}: cannot read: {exc.strerror or exc}"


def failure_row(loop: str, source: str, error: str, scope: str = "loop") -> dict[str, Any]:
    """A failed summary row; ``scope`` (`report.FAILED_SCOPES`) says whether a loop, a whole file
    or an input path failed, so a file that could not be read is not counted as a loop."""
    return {"loop": loop, "status": "failed", "source": source, "error": error, "scope": scope}


# ----------------------------------------------------------------------------------------------
# one loop, one file (run in workers)


def loop_row(diag: Diagnosis, report: str | None) -> dict[str, Any]:
    """The summary row of one diagnosed loop (also stored as ``summary`` in its ``LOOP.json``)."""
    ident = diag.identification

    def r4(v: float | None) -> float | None:
        return None if v is None else round(float(v), 4)

    def sig4(v: float | None) -> float | None:
        return None if v is None else float(f"{float(v):.4g}")

    si, ji = ident.S_interval_pct, ident.J_interval_pct
    period = ident.oscillation.period_s
    act = {} if ident.activity is None else ident.activity.to_dict()
    return _sized({
        "loop": diag.loop_id or ident.loop,
        "status": "ok",
        "severity": diag.severity.score,
        "verdict": diag.verdict_text,
        "class": ident.cls,
        "sticky": bool(ident.stiction),
        "S_pct": r4(ident.S_pct), "S_lo": None if si is None else r4(si[0]), "S_hi": None if si is None else r4(si[1]),
        "J_pct": r4(ident.J_pct), "J_lo": None if ji is None else r4(ji[0]), "J_hi": None if ji is None else r4(ji[1]),
        # significant digits, not decimals: a probability of 3e-5 is "< 1 %", not a rounded 0
        "stiction_probability": sig4(ident.stiction_probability),
        "confidence": sig4(ident.confidence),
        "oscillation_period_s": r4(period) if ident.loop_oscillates else None,
        "slow_cycle_period_s": r4(period) if ident.slow_cycle else None,
        # the units of S, J and OP's travel, as the loop's report gives them
        "sj_units": ident.op_units,
        "sj_in_op_units": ident.op_units != "% of span",
        # valve activity: OP's travel (in sj_units per day) and reversals per day, noise kept out
        "travel_pct_per_day": act.get("travel_pct_per_day"),
        "reversals_per_day": act.get("reversals_per_day"),
        "warnings": len(diag.warnings),
        "data_quality_warnings": sum(1 for w in diag.warnings if w.code.startswith("data_quality.")),
        "degradation": diag.degradation,
        "sticky_runs": None if diag.sticky_runs is None else list(diag.sticky_runs),
        "action": diag.action,
        "report": report,
        "source": diag.record.source,
        "error": None,
        "input_hash": diag.input_hash,
        "skipped": False,
        "seconds": round(sum(diag.timings_s.values()), 4),
    })


def _sized(row: dict[str, Any]) -> dict[str, Any]:
    """A summary row with S, J and their intervals only when its verdict is stiction: they size the
    stiction found (docs/verdict.md), and for a healthy loop a 0.00 would read as a measured clean
    valve. The history keeps the full result."""
    from .history import SIZE_COLUMNS

    if not row.get("sticky"):
        row.update(dict.fromkeys(SIZE_COLUMNS))
    return row


def stored_row(stored: Mapping[str, Any]) -> dict[str, Any] | None:
    """The summary row of a loop done in an earlier run, from its ``LOOP.json`` (None when the file
    predates stored rows: the loop is diagnosed again)."""
    row = stored.get("summary")
    if not isinstance(row, Mapping):
        return None
    from .history import row_from_stored

    out = _sized(dict(row, skipped=True))   # rows written before healthy loops' S/J were left empty too
    out["_history"] = row_from_stored(stored)
    return out


def _loop_dir(cfg: BatchConfig, loop_id: str) -> Path:
    return Path(cfg.out_dir) / "loops" / loop_id


def _existing(cfg: BatchConfig, loop_id: str) -> dict[str, Any] | None:
    p = _loop_dir(cfg, loop_id) / f"{loop_id}.json"
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _tag(record: Any) -> str:
    """The file-safe name of the loop a record belongs to (its history is filed under it)."""
    return safe_name(record.name)


def _claim(cfg: BatchConfig, name: str, owner: str) -> bool:
    """Claim a report name for ``owner`` (an input file); True when it is, or already was, ours.

    The claim is a file under ``OUT/.stiction/names/`` created by a hard link, which succeeds for
    one process only and never shows a half-written owner, so parallel workers never share a name.
    """
    d = Path(cfg.out_dir) / STATE_DIR / "names"
    d.mkdir(parents=True, exist_ok=True)
    claim = d / f"{name}.owner"
    try:
        return claim.read_text(encoding="utf-8") == owner
    except OSError:
        pass
    prev = _existing(cfg, name)  # an output folder written before names were claimed
    prev_src = (prev or {}).get("record", {}).get("source") if isinstance(prev, Mapping) else None
    if prev_src and str(Path(prev_src).resolve()) != owner:
        return False
    tmp = d / f".{name}.{os.getpid()}.tmp"
    tmp.write_text(owner, encoding="utf-8")
    try:
        os.link(tmp, claim)
        return True
    except FileExistsError:
        return claim.read_text(encoding="utf-8") == owner
    finally:
        tmp.unlink(missing_ok=True)


def _choose_loop_id(cfg: BatchConfig, record: Any, path: Path) -> str:
    """The loop's report name: its tag, or ``TAG__FILE`` when another input holds the same tag."""
    base = _tag(record)
    nseg = record.meta.get("n_segments") or 1
    if nseg > 1:
        base += f"_seg{int(record.meta.get('segment', 0)) + 1}"
    owner = str(path.resolve())
    stem = safe_name(path.stem)
    digest = hashlib.sha1(owner.encode("utf-8")).hexdigest()[:8]
    for name in (base, f"{base}__{stem}", f"{base}__{stem}_{digest}"):
        if _claim(cfg, name, owner):
            return name
    raise StictionError(f"{path}: no free report name for loop {record.name!r}")  # pragma: no cover


def write_loop_outputs(cfg: BatchConfig, diag: Diagnosis, loop_id: str, *,
                       history_rows: Sequence[Mapping[str, Any]] = ()) -> tuple[str, Diagnosis]:
    """Figures, Markdown, PDF, then JSON (the done marker) of one loop. Returns the report's path
    relative to the output folder and the diagnosis with the report's time in its timings."""
    from . import figures as figs
    from .history import end_of_record
    from .report import loop_blocks, to_markdown

    t0 = time.perf_counter()
    d = _loop_dir(cfg, loop_id)
    d.mkdir(parents=True, exist_ok=True)
    for stale in d.glob(".*.tmp"):  # left by a killed job
        stale.unlink(missing_ok=True)
    rec, ident = diag.record, diag.identification
    hist_for_fig = list(history_rows) + ([{"run_at": "this run", "data_end": end_of_record(rec.start, rec.n, rec.ts_s),
                                           "S_pct": ident.S_pct, "J_pct": ident.J_pct, "sj_units": ident.op_units}]
                                         if history_rows else [])
    pngs = figs.loop_figures(diag, hist_for_fig)
    for name, png in pngs.items():
        atomic_write(d / f"{name}.png", png)
    blocks = loop_blocks(diag, list(pngs), history_rows=list(history_rows))
    atomic_write(d / f"{loop_id}.md", to_markdown(blocks))
    if cfg.pdf:
        from .pdf import to_pdf

        atomic_write(d / f"{loop_id}.pdf", to_pdf(blocks, pngs, title=f"Stiction report {loop_id}"))
    else:
        # an earlier run's PDF would sit beside this run's Markdown and JSON and say something else
        (d / f"{loop_id}.pdf").unlink(missing_ok=True)
    # figures, Markdown, PDF
    diag = replace(diag, timings_s={**diag.timings_s, "report": time.perf_counter() - t0})
    report = f"loops/{loop_id}/{loop_id}.md"
    result = diag.to_dict()
    result["summary"] = loop_row(diag, report)
    atomic_write(d / f"{loop_id}.json", json.dumps(result, indent=1, allow_nan=False))
    return report, diag


def process_record(cfg: BatchConfig, record: Any, path: Path, digest: str) -> dict[str, Any]:
    """Diagnose one record and write its outputs; a summary row (``status`` ok or failed) with the
    loop's history row under ``_history``."""
    from .history import (degradation as degrade, end_of_record, previous_runs, row_from_diagnosis, sticky_runs,
                          verdict_of)
    from .pipeline import diagnose, recommended_action

    loop_id = _choose_loop_id(cfg, record, path)
    ih = input_hash(digest, cfg.result_key(), record.name, record.meta.get("segment"))
    prev = _existing(cfg, loop_id)
    # a loop done before is reused, unless this run wants the PDF that run did not write
    pdf_missing = cfg.pdf and not (_loop_dir(cfg, loop_id) / f"{loop_id}.pdf").exists()
    if prev is not None and prev.get("input_hash") == ih and not pdf_missing:
        row = stored_row(prev)
        if row is not None:
            return row
    try:
        diag = diagnose(record, explain=cfg.explain, narx=cfg.narx, threads=cfg.threads)
        end = end_of_record(record.start, record.n, record.ts_s)
        hist = [r for r in previous_runs(cfg.db, _tag(record), exclude_hash=ih)
                if end is None or not r.get("data_end") or r["data_end"] < end]
        # this run with its verdict: a run that says no stiction has no size to grow from (it
        # neither breaks nor extends the growth), as in `stiction history`
        warn = degrade(hist + [{"run_at": "this run", "data_end": end, "S_pct": diag.identification.S_pct,
                                **verdict_of(diag.identification)}]) if hist else None
        held = sticky_runs(hist + [verdict_of(diag.identification)])
        runs = None if held is None else held[:2]
        diag = replace(diag, loop_id=loop_id, input_hash=ih, degradation=warn, sticky_runs=runs,
                       action=recommended_action(diag.identification, diag.warnings, runs))
        report, diag = write_loop_outputs(cfg, diag, loop_id, history_rows=hist)
        row = loop_row(diag, report)
        row["_history"] = row_from_diagnosis(diag, input_hash=ih)
        return row
    except MemoryError:
        raise
    except Exception as exc:  # a failing loop is recorded, the batch goes on
        row = failure_row(loop_id, str(path), _one_line(exc))
        if not isinstance(exc, StictionError):
            row["traceback"] = traceback.format_exc(limit=6)
        return row


_SPACES = (re.compile(r"\s{2,}"), re.compile(r"\s+"))


def whitespace_export(path: str | os.PathLike) -> io.StringIO | None:
    """A space-aligned text export (``.prn``: columns padded with blanks) as tab-separated text,
    or None when the file is not one (it has tabs, commas or semicolons, or ragged columns).

    Columns are split at runs of two or more blanks when that gives every line the same number of
    fields (a date and a time separated by one blank stay one cell), else at any blank.
    """
    text = Path(path).read_text(encoding="utf-8-sig", errors="replace")
    lines = text.splitlines()
    head = [ln.strip() for ln in lines[:50] if ln.strip()]
    if len(head) < 2 or any(c in ln for ln in head for c in "\t,;"):
        return None
    for pat in _SPACES:
        widths = {len(pat.split(ln)) for ln in head}
        if len(widths) == 1 and min(widths) >= 2:
            buf = io.StringIO("\n".join("\t".join(pat.split(ln.strip())) if ln.strip() else "" for ln in lines))
            buf.name = str(path)  # errors name the file
            return buf
    return None


def read_file(cfg: BatchConfig, path: Path) -> list[Any]:
    """The records of one file. A tag map applies where it names a loop in the file; a file where
    it names none is read by the naming rule (with the map's reading options), with a finding that
    says so. A space-aligned
    ``.prn`` export is read as the table it is."""
    from connectors import read_records

    def read(**extra: Any) -> list[Any]:
        if path.suffix.lower() == ".prn":
            table = whitespace_export(path)
            if table is not None:
                return read_records(table, **opts, **extra)
        return read_records(str(path), **opts, **extra)

    opts = dict(cfg.read_options)
    opts.pop("loop", None)  # a file without the loop is left alone, not failed (process_file)
    if not cfg.tags:
        return read()
    try:
        return read(tags=cfg.tags)
    except StictionError as exc:
        tag_error = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    from connectors import with_tag_map_options

    # only the loops' names fall back to the naming rule: the map's reading options (date order,
    # time zone, format) are the plant's and read this file too
    opts = with_tag_map_options(opts, cfg.tags)
    try:
        records = read()
    except StictionError as exc:
        raise DataError(f"{tag_error}; without the tag map: {_one_line(exc)}") from None
    from ..record import Finding

    note = Finding("tag_map", f"the tag map {Path(cfg.tags).name} names no loop in this file; its loops "
                   "were found by the naming rule", "info", {"tag_map": str(cfg.tags)})
    return [r.with_findings(note) for r in records]


def file_configs(cfg: BatchConfig, files: Sequence[Path]) -> list[BatchConfig]:
    """Each file's config: the batch's, with the date order its folder's files say together
    (`connectors.date_orders`) where the file alone cannot say it (every day and month 12 or
    less, as in a one-day export). ``--dayfirst``/``--monthfirst`` or a tag map's ``dayfirst``
    decide alone (`connectors.date_orders` leaves every file alone then). The order given is part
    of the file's input hash, as any read option is."""
    from connectors import date_orders

    out = [cfg] * len(files)
    opts = {k: v for k, v in cfg.read_options.items() if k not in ("loop", "max_samples")}
    if cfg.tags:
        # the map's reading options (fmt, tz, dayfirst) read the dates as the files will be read
        opts["tags"] = cfg.tags
    folders: dict[Path, list[int]] = {}
    for k, f in enumerate(files):
        folders.setdefault(f.parent, []).append(k)
    for idx in folders.values():
        if len(idx) < 2:
            continue
        for k, order in zip(idx, date_orders([_source(files[k]) for k in idx], **opts)):
            if order is not None:
                out[k] = replace(cfg, read_options={**cfg.read_options, "dayfirst": order})
    return out


def _source(path: Path) -> Any:
    """A file as `read_file` reads it: a space-aligned ``.prn`` as its table, else the path."""
    if path.suffix.lower() == ".prn":
        try:
            return whitespace_export(path) or str(path)
        except OSError:
            return str(path)
    return str(path)


def process_file(cfg: BatchConfig, path: str) -> dict[str, Any]:
    """One task: read a file, diagnose every loop in it. Returns ``{"path", "digest", "rows"}``."""
    worker_setup()
    p = Path(path)
    try:
        digest = _file_digest(p)
        records = read_file(cfg, p)
        if not records:
            raise DataError(f"{p}: no loops found in this file")
    except MemoryError:
        raise
    except Exception as exc:
        return {"path": str(p), "digest": None,
                "rows": [failure_row(safe_name(p.stem), str(p), _one_line(exc), "file")]}
    want = cfg.read_options.get("loop")
    if want:
        names = sorted({r.name for r in records})
        from ..api import records_named

        records = records_named(records, str(want))
        if not records:
            return {"path": str(p), "digest": None, "rows": [],
                    "left_alone": [{"path": str(p), "reason": f"no loop named {want!r} (loops: {', '.join(names)})"}]}
    # tags with an OP or a PV column but not both: the summary says so, or they vanish unremarked
    incomplete: dict[str, str] = {}
    for rec in records:
        for f in rec.findings:
            if f.code == "loop_left_out":
                incomplete.update(f.data.get("tags", {}))
    left_alone = [{"path": str(p), "reason": f"a loop without {role}: {tag}"}
                  for tag, role in sorted(incomplete.items())]
    import resource
    import time

    rows = []
    for rec in records:
        cpu0 = time.process_time()
        rows.append(process_record(cfg, rec, p, digest))
        # this process's CPU time on the loop (all its threads): a pool's workers are not children
        # the batch can take resource usage of (multiprocessing's fork server started them)
        rows[-1]["cpu_s"] = round(time.process_time() - cpu0, 3)

    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KiB on Linux
    for r in rows:
        r["worker_peak_rss_mib"] = round(rss, 1)
    return {"path": str(p), "digest": digest, "rows": rows, "left_alone": left_alone}


_SETUP_DONE = False


def worker_setup(parent_pid: int | None = None) -> None:
    """Once per process: one thread per worker for BLAS/OpenMP/torch (the pool gives parallelism);
    in a worker process of a pool (``parent_pid`` given), die with the process that started it."""
    global _SETUP_DONE
    if parent_pid is not None:
        import signal

        # Ctrl-C reaches the whole process group; the batch answers it by stopping its workers
        # (`_Pool.abort`), and a worker interrupted on its own would abandon the task queue mid-read
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        die_with_parent(parent_pid)
    if _SETUP_DONE:
        return
    _SETUP_DONE = True
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    torch = sys.modules.get("torch")
    if torch is not None:
        try:
            torch.set_num_threads(1)
        except Exception:  # pragma: no cover
            pass


#: How often (seconds) a worker checks that the process that started it is still there.
PARENT_POLL_S = 0.5
_WATCHING: int | None = None


def _start_time(pid: int) -> str | None:
    """The kernel's start time of a live process (guards against a reused pid), None when the
    process is gone or a zombie (killed, not yet reaped)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as fh:
            stat = fh.read().decode("ascii", "replace")
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()
    if not fields or fields[0] in ("Z", "X"):
        return None
    return fields[19] if len(fields) > 19 else "?"


def die_with_parent(parent_pid: int) -> None:
    """Make this (worker) process exit as soon as ``parent_pid`` dies, even by ``kill -9``.

    Two guards: the kernel's parent-death signal (Linux ``PR_SET_PDEATHSIG``), which fires when
    this process's own parent exits (a pool's forkserver exits with the batch), and a daemon thread
    that polls ``parent_pid`` itself every `PARENT_POLL_S` seconds (any Unix; the batch may be a
    grandparent). Without them a killed batch leaves workers that finish their files for minutes.
    """
    global _WATCHING
    if _WATCHING == parent_pid or parent_pid == os.getpid():
        return
    _WATCHING = parent_pid
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            import signal

            libc = ctypes.CDLL(None, use_errno=True)
            PR_SET_PDEATHSIG = 1
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the thread still watches
            pass
    start = _start_time(parent_pid) if os.path.isdir("/proc") else None

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if start is not None:
                gone = _start_time(parent_pid) != start
            else:
                try:
                    os.kill(parent_pid, 0)
                    gone = False
                except ProcessLookupError:
                    gone = True
                except PermissionError:
                    gone = False
            if gone:
                os._exit(70)

    import threading

    threading.Thread(target=watch, name="stiction-parent-watch", daemon=True).start()


# ----------------------------------------------------------------------------------------------
# state (whole-file skip)


def _state_path(cfg: BatchConfig, path: str) -> Path:
    key = hashlib.sha1(str(Path(path).resolve()).encode("utf-8")).hexdigest()[:20]
    return Path(cfg.out_dir) / STATE_DIR / "files" / f"{key}.json"


def _load_state(cfg: BatchConfig, path: str, digest: str) -> list[dict[str, Any]] | None:
    """The rows of a file already done with this content and these options, or None."""
    try:
        st = json.loads(_state_path(cfg, path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if st.get("digest") != digest or st.get("options") != cfg.options_key():
        return None
    rows = []
    for loop_id in st.get("loops", []):
        res = _existing(cfg, loop_id)
        row = None if res is None else stored_row(res)
        if row is None:
            return None
        rows.append(row)
    return rows


def _save_state(cfg: BatchConfig, outcome: Mapping[str, Any]) -> None:
    rows = outcome["rows"]
    if outcome.get("digest") is None or any(r["status"] != "ok" for r in rows):
        return  # failures are retried next time
    st = {"path": outcome["path"], "digest": outcome["digest"], "options": cfg.options_key(),
          "loops": [r["loop"] for r in rows]}
    atomic_write(_state_path(cfg, outcome["path"]), json.dumps(st))


# ----------------------------------------------------------------------------------------------
# progress


class Progress:
    """A progress bar on stderr (one line redrawn on a terminal, a line per 10 % otherwise)."""

    def __init__(self, total: int, *, stream: Any = None, enabled: bool = True, label: str = "loops") -> None:
        self.total = max(total, 0)
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.label = label
        self.done = 0
        self.failed = 0
        self.skipped = 0
        self.t0 = time.monotonic()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._last_decile = -1

    def update(self, files: int = 1, *, failed: int = 0, skipped: int = 0) -> None:
        self.done += files
        self.failed += failed
        self.skipped += skipped
        if not self.enabled:
            return
        frac = self.done / self.total if self.total else 1.0
        el = time.monotonic() - self.t0
        eta = el / frac - el if frac > 0 else 0.0
        width = 30
        bar = "#" * int(frac * width) + "-" * (width - int(frac * width))
        text = (f"[{bar}] {self.done}/{self.total} files {frac:4.0%}  failed {self.failed}  "
                f"skipped {self.skipped}  {el:5.0f} s elapsed, ~{eta:.0f} s left")
        if self._tty:
            self.stream.write("\r" + text)
            if self.done >= self.total:
                self.stream.write("\n")
        else:
            decile = int(frac * 10)
            if decile != self._last_decile or self.done >= self.total:
                self._last_decile = decile
                self.stream.write(text + "\n")
        self.stream.flush()


# ----------------------------------------------------------------------------------------------
# executors


class _Inline:
    """Runs tasks in this process, one after another (``workers=1``), as they are collected."""

    def submit(self, fn: Callable, *args: Any) -> Future:
        fut: Future = Future()
        fut._stiction_task = (fn, args)  # type: ignore[attr-defined]
        return fut

    def as_completed(self, futures: Sequence[Future]) -> Iterator[Future]:
        for fut in futures:
            fn, args = fut._stiction_task  # type: ignore[attr-defined]
            try:
                fut.set_result(fn(*args))
            except BaseException as exc:
                if isinstance(exc, KeyboardInterrupt):
                    raise
                fut.set_exception(exc)
            yield fut

    def close(self) -> None:
        pass


class _Pool:
    def __init__(self, workers: int) -> None:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        # forkserver: workers start from a clean process, safe when the parent has threads (torch).
        ctx = mp.get_context("forkserver")
        self.ex = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=worker_setup,
                                      initargs=(os.getpid(),))

    def submit(self, fn: Callable, *args: Any) -> Future:
        return self.ex.submit(fn, *args)

    def as_completed(self, futures: Sequence[Future]) -> Iterator[Future]:
        from concurrent.futures import as_completed

        return as_completed(futures)

    def close(self) -> None:
        self.ex.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """Stop at once (Ctrl-C): cancel what has not started and kill the workers.

        Waiting for the workers instead is what hangs: files already handed to them would run to
        the end, and a worker signalled while reading its next task can leave the task queue half
        read, so the pool waits forever. What a worker finished is on disk (``LOOP.json`` is
        written last), so a re-run resumes it; what it had half written is left as temporary files
        that the next run clears.
        """
        import signal

        procs = list((getattr(self.ex, "_processes", None) or {}).values())  # shutdown() forgets them
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not cut this short
        try:
            self.ex.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                p.terminate()
            for p in procs:
                p.join(2.0)
                if p.is_alive():
                    p.kill()
                    p.join(2.0)
        finally:
            signal.signal(signal.SIGINT, old)


class _Dask:
    def __init__(self, scheduler: str, workers: int) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise StictionError("--scheduler needs Dask distributed: pip install 'stiction[dask]'") from None
        self.cluster = None
        if scheduler == "local":
            self.cluster = LocalCluster(n_workers=max(workers, 1), threads_per_worker=1, processes=True,
                                        dashboard_address=None, silence_logs=40)
            self.client = Client(self.cluster)
        else:
            try:
                self.client = Client(scheduler, timeout="20s")
            except (OSError, ValueError, TypeError) as exc:
                # ValueError: an address Dask cannot parse (no port, unknown protocol)
                raise StictionError(f"cannot reach the Dask scheduler at {scheduler!r}: {exc} (give 'local' or an "
                                    "address such as tcp://10.0.0.5:8786)") from None
        self.client.run(worker_setup)

    def submit(self, fn: Callable, *args: Any) -> Any:
        return self.client.submit(fn, *args, pure=False)

    def as_completed(self, futures: Sequence[Any]) -> Iterator[Any]:
        from distributed import as_completed

        return iter(as_completed(futures))

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def make_executor(workers: int, scheduler: str | None) -> Any:
    if scheduler:
        return _Dask(scheduler, workers)
    if workers <= 1:
        return _Inline()
    return _Pool(workers)


# ----------------------------------------------------------------------------------------------
# the batch


@dataclass
class BatchResult:
    rows: list[dict[str, Any]]
    out_dir: Path
    n_files: int
    elapsed_s: float
    #: whether PDF reports were written
    pdf: bool = True
    #: files found in the input folders and left alone (``{"path", "reason"}``)
    skipped_files: list[dict[str, Any]] = field(default_factory=list)

    @property
    def n_failed(self) -> int:
        return sum(1 for r in self.rows if r["status"] != "ok")

    @property
    def counts(self) -> dict[str, int]:
        """`report.tally` of the rows: loops found, diagnosed and failed; files and inputs not read."""
        return tally(self.rows)

    @property
    def n_skipped(self) -> int:
        return sum(1 for r in self.rows if r.get("skipped"))

    @property
    def summary_md(self) -> Path:
        return self.out_dir / "summary.md"


def rank(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Ok loops by severity (then S, then name) descending with ranks 1..n, then failures by name."""
    rows = list(rows)
    ok = sorted((r for r in rows if r["status"] == "ok"),
                key=lambda r: (-(r.get("severity") or 0.0), -(r.get("S_pct") or 0.0), str(r["loop"])))
    bad = sorted((r for r in rows if r["status"] != "ok"), key=lambda r: (str(r["loop"]), str(r.get("source"))))
    for i, r in enumerate(ok, 1):
        r["rank"] = i
    for r in bad:
        r["rank"] = None
    return ok + bad


def _csv_cell(value: Any) -> Any:
    # sticky_runs (k, m) reads as "k/m", as in the summary's table
    if value is None:
        return ""
    if isinstance(value, (list, tuple)):
        return "/".join(str(v) for v in value)
    return value


#: The plant summary's files, in the order they are moved into place: ``summary.json`` last, so
#: that the one machines read names the run whose set is complete.
SUMMARY_FILES = ("summary.csv", "summary.md", "summary.pdf", "summary.json")
_SUMMARY_STAGE = "summary-next"
#: Beside a staged set, ``NAME.absent`` says the set has no ``NAME`` (a run without PDFs): moving
#: the set into place removes the earlier run's file of that name.
_ABSENT = ".absent"
_RUN_MARK = re.compile(r"<!-- stiction run (\S+) -->")


def new_run_id() -> str:
    """An id for one batch's summary set, carried by each of its files."""
    import uuid

    return uuid.uuid4().hex[:16]


def write_summary(out_dir: Path, rows: Sequence[Mapping[str, Any]], *, pdf: bool = True,
                  meta: Mapping[str, Any] | None = None,
                  skipped_files: Sequence[Mapping[str, Any]] = ()) -> str:
    """``summary.csv``, ``summary.md``, ``summary.pdf`` and ``summary.json`` as one set; returns its run id.

    Each file is atomic, but four renames are not one: a kill between them would leave some files
    of this run beside others of the last. So all four are written first into
    ``OUT/.stiction/summary-next/``, which a ``complete`` file then marks whole, and only then moved
    into place in the order of `SUMMARY_FILES`. Each carries the run id (``run_id`` in the JSON, a
    ``run_id`` column in the CSV, a ``<!-- stiction run ID -->`` line ending the Markdown, the PDF's
    subject): a set is one run's when its files carry ``summary.json``'s id. A set cut off before it
    was whole is dropped; one cut off while being moved is finished by the next batch on the folder
    (`finish_summary`).
    """
    from .report import summary_blocks, to_markdown

    meta = dict(meta or {})
    run_id = str(meta.setdefault("run_id", new_run_id()))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=[*SUMMARY_COLUMNS, "run_id"], extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({**{k: _csv_cell(r.get(k)) for k in SUMMARY_COLUMNS}, "run_id": run_id})
    files: dict[str, str | bytes] = {"summary.csv": buf.getvalue()}
    clean = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    t = tally(rows)
    doc = {**meta, "n_loops": t["loops"], "n_failed": sum(1 for r in rows if r["status"] != "ok"),
           "n_files_failed": t["files_failed"], "n_inputs_failed": t["inputs_failed"],
           "loops": clean, "skipped_files": [dict(f) for f in skipped_files]}
    kw = {"generated_at": meta.get("generated_at"), "tool_version": meta.get("tool_version"),
          "skipped_files": skipped_files}
    files["summary.md"] = to_markdown(summary_blocks(rows, **kw)).rstrip("\n") + f"\n\n<!-- stiction run {run_id} -->\n"
    if pdf:
        from .pdf import to_pdf

        files["summary.pdf"] = to_pdf(summary_blocks(rows, links=False, **kw), title="Plant stiction summary",
                                      subject=f"stiction run {run_id}")
    files["summary.json"] = json.dumps(doc, indent=1, default=str)
    stage = Path(out_dir) / STATE_DIR / _SUMMARY_STAGE
    _drop(stage)   # a set an earlier run did not finish writing
    (stage / "complete").unlink(missing_ok=True)   # never beside a set that is not whole
    for name, data in files.items():
        atomic_write(stage / name, data)
    for name in SUMMARY_FILES:
        if name not in files:
            atomic_write(stage / f"{name}{_ABSENT}", run_id)
    atomic_write(stage / "complete", run_id)
    finish_summary(out_dir)
    return run_id


def finish_summary(out_dir: str | os.PathLike) -> None:
    """Move a complete staged summary set into place (`write_summary`); drop one that is not complete.

    Run at the start of every batch (under the folder's lock), so that a batch killed while moving
    its summary into place leaves the set of that run, not a mix with the run before."""
    out = Path(out_dir)
    stage = out / STATE_DIR / _SUMMARY_STAGE
    if not (stage / "complete").is_file():
        _drop(stage)
        return
    for name in SUMMARY_FILES:
        try:
            if (stage / name).is_file():
                os.replace(stage / name, out / name)
            elif (stage / f"{name}{_ABSENT}").is_file():
                # a set without this file (``--no-pdf``): an earlier run's would pass for this one's
                (out / name).unlink(missing_ok=True)
            else:   # moved already by a batch cut off while finishing this set
                continue
        except OSError as exc:
            raise DataError(f"{out / name}: cannot write: {exc.strerror or exc}") from None
        _sync_dir(out)   # the renames reach the disk in this order: summary.json last
    _drop(stage)


def _drop(folder: Path) -> None:
    """Remove the staging folder (it holds files only)."""
    if not folder.is_dir():
        return
    try:
        for p in folder.iterdir():
            p.unlink(missing_ok=True)
        folder.rmdir()
    except OSError:  # left for the next run to clear
        pass


def _sync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover - a file system that cannot sync a folder
        pass
    finally:
        os.close(fd)


def summary_run_ids(out_dir: str | os.PathLike) -> dict[str, str | None]:
    """The run id each summary file in ``out_dir`` carries (None where a file is missing or
    carries none; the PDF is not read): the set is one run's when these agree with ``summary.json``."""
    out = Path(out_dir)
    ids: dict[str, str | None] = {}
    try:
        ids["summary.json"] = json.loads((out / "summary.json").read_text(encoding="utf-8")).get("run_id")
    except (OSError, ValueError, AttributeError):
        ids["summary.json"] = None
    try:
        with open(out / "summary.csv", newline="", encoding="utf-8") as fh:
            got = {r.get("run_id") for r in csv.DictReader(fh)}
        ids["summary.csv"] = got.pop() if len(got) == 1 else None
    except (OSError, csv.Error):
        ids["summary.csv"] = None
    try:
        m = _RUN_MARK.search((out / "summary.md").read_text(encoding="utf-8"))
        ids["summary.md"] = m.group(1) if m else None
    except OSError:
        ids["summary.md"] = None
    return ids


def run_batch(inputs: Sequence[str | os.PathLike], out_dir: str | os.PathLike, *,
              workers: int | None = None, scheduler: str | None = None, tags: str | None = None,
              read_options: Mapping[str, Any] | None = None, explain: bool | str = False, narx: bool = True,
              pdf: bool = True, db: str | os.PathLike | None = None, history: bool = True,
              progress: bool = True, stream: Any = None) -> BatchResult:
    """Diagnose every loop found in ``inputs``; write per-loop reports and the plant summary.

    Parameters
    ----------
    inputs : paths
        Files and/or folders (searched recursively).
    out_dir : path
        Output folder (created).
    workers : int, optional
        Worker processes (default: the machine's CPU count); 1 runs inline.
    scheduler : str, optional
        ``"local"`` for a Dask LocalCluster of ``workers`` processes, or a Dask scheduler address
        (``tcp://host:8786``).
    db : path, optional
        History database (`diagnose.service.history.default_db_path()` when None); ``history=False``
        leaves it alone.

    Returns
    -------
    BatchResult
        ``n_failed > 0`` when any file or loop failed.
    """
    from .history import History, default_db_path, utc_now
    from .pipeline import tool_version

    t0 = time.monotonic()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise DataError(f"{out}: is a file; --out must be a folder (the reports and the summary go into it)")
    # a bad --tags or --db (a folder, a damaged file, a read-only place) is said before the output
    # folder and its lock exist: a refused run leaves nothing behind
    if tags is not None:
        if not Path(tags).is_file():
            raise DataError(f"{tags}: tag map not found; give an existing TOML file with --tags")
        from connectors.tagmap import load_tagmap

        load_tagmap(tags)  # a broken map is reported once, up front, not once per file
    if history:
        History(db if db is not None else default_db_path()).close()
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"{out}: cannot create the output folder: {exc.strerror or exc}") from None
    lock = lock_out_dir(out)  # one batch at a time per output folder: two would overwrite one summary
    try:
        finish_summary(out)   # the summary set of a batch killed while moving it into place
        return _run_batch(inputs, out, t0, workers=workers, scheduler=scheduler, tags=tags,
                          read_options=read_options, explain=explain, narx=narx, pdf=pdf, db=db,
                          history=history, progress=progress, stream=stream)
    except DataError:
        # refused before anything was written (no input found): the folder this run made goes too
        lock.close()
        if created:
            _remove_if_only_lock(out)
        raise
    finally:
        lock.close()  # the kernel drops the lock with the process too (kill -9 leaves none behind)


def _remove_if_only_lock(out: Path) -> None:
    """Remove ``out`` when it holds nothing but the batch's lock (``.stiction/lock``)."""
    try:
        if {p.relative_to(out).as_posix() for p in out.rglob("*")} <= {".stiction", ".stiction/lock"}:
            (out / ".stiction" / "lock").unlink(missing_ok=True)
            (out / ".stiction").rmdir()
            out.rmdir()
    except OSError:
        pass        # something else appeared there meanwhile: leave it


def lock_out_dir(out: Path) -> Any:
    """Take ``out/.stiction/lock`` (an exclusive ``flock``, held until the returned file is closed),
    or raise a one-line `DataError` naming the folder: when another batch holds it (with its process
    id), or when the folder cannot be written (read-only, no permission), before anything runs."""
    import fcntl

    path = out / ".stiction" / "lock"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        f = open(path, "a+")
    except OSError as exc:
        raise DataError(f"{out}: cannot write to the output folder: {exc.strerror or exc}") from None
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        pid = f.read().strip()
        f.close()
        raise DataError(f"{out}: another stiction batch{f' (process {pid})' if pid.isdigit() else ''} "
                        "is writing to this output folder; wait for it to finish or give another --out") from None
    f.seek(0)
    f.truncate()
    f.write(str(os.getpid()))
    f.flush()
    return f


def _run_batch(inputs: Sequence[str | os.PathLike], out: Path, t0: float, *, workers: int | None,
               scheduler: str | None, tags: str | None, read_options: Mapping[str, Any] | None,
               explain: bool | str, narx: bool, pdf: bool, db: str | os.PathLike | None, history: bool,
               progress: bool, stream: Any) -> BatchResult:
    from .history import History, default_db_path, utc_now
    from .pipeline import tool_version

    db_path = Path(db) if db is not None else default_db_path()
    from ..api import check_read_options

    cfg = BatchConfig(out_dir=str(out), read_options=check_read_options(read_options or {}, diagnosis=True),
                      tags=tags, explain=explain, narx=narx, pdf=pdf, db=str(db_path) if history else None)
    skipped_files: list[dict[str, Any]] = []
    files, missing = discover(inputs, exclude=[out], skipped=skipped_files)
    workers = workers or usable_cores()
    rows: list[dict[str, Any]] = [dict(m, file=m["source"]) for m in missing]
    bar = Progress(len(files), stream=stream, enabled=progress)
    hist = History(db_path) if history else None
    if not files:
        # nothing to diagnose: a one-line error, as for an empty folder, and no summary of nothing
        if hist is not None:
            hist.close()
        if missing:
            raise DataError("; ".join(m["error"] for m in missing))
        raise DataError("no input files found (looked for " + ", ".join(INPUT_SUFFIXES) +
                        f" in {', '.join(map(str, inputs))})")
    run_at = utc_now()

    def collect(outcome: Mapping[str, Any], skipped_file: bool = False) -> None:
        frows = outcome["rows"]
        shown = shown_path(outcome["path"], inputs)
        for r in frows:  # set here, not in the worker: a row stored by an earlier run has none
            r["file"] = shown
        skipped_files.extend(dict(d) for d in outcome.get("left_alone") or ())
        if hist is not None:
            hist.add_rows([dict(r["_history"], run_at=run_at)
                           for r in frows if r["status"] == "ok" and "_history" in r])  # filed by tag
        if not skipped_file:
            _save_state(cfg_of.get(str(outcome["path"]), cfg), outcome)
        rows.extend(frows)
        bar.update(failed=sum(1 for r in frows if r["status"] != "ok"),
                   skipped=sum(1 for r in frows if r.get("skipped")))

    todo: list[tuple[str, BatchConfig]] = []
    # a folder's files are one export: they share one date order (05/03/2026 alone cannot say it)
    cfg_of = {str(f): c for f, c in zip(files, file_configs(cfg, files))}
    try:
        for f in files:
            fcfg = cfg_of[str(f)]
            try:
                digest = _file_digest(f)
            except OSError as exc:
                collect({"path": str(f), "digest": None,
                         "rows": [failure_row(safe_name(f.stem), str(f), _read_error(f, exc), "file")]})
                continue
            done = _load_state(fcfg, str(f), digest)
            if done is not None:
                collect({"path": str(f), "digest": digest, "rows": done}, skipped_file=True)
            else:
                todo.append((str(f), fcfg))
        if todo:
            n_exec = min(workers, len(todo)) if not scheduler else workers
            ex = make_executor(n_exec, scheduler)
            # a worker's fits use threads too: share the cores out, or workers x threads
            # oversubscribe them (a remote scheduler's machines are not known: one thread each)
            local = scheduler in (None, "local")
            threads = cores_per_worker(n_exec) if local else 1
            try:
                futures = [ex.submit(process_file, replace(fcfg, threads=threads), f) for f, fcfg in todo]
                path_of = {id(fu): f for fu, (f, _) in zip(futures, todo)}
                for fu in ex.as_completed(futures):
                    try:
                        outcome = fu.result()
                    except Exception as exc:  # a worker died (memory, signal): record, go on
                        f = path_of.get(id(fu), "?")
                        outcome = {"path": f, "digest": None,
                                   "rows": [failure_row(safe_name(Path(f).stem), f, _one_line(exc), "file")]}
                    collect(outcome)
            except BaseException:  # Ctrl-C above all: stop now, do not wait for the workers
                getattr(ex, "abort", ex.close)()
                raise
            else:
                ex.close()
    finally:
        if hist is not None:
            hist.close()
    ranked = rank(rows)
    meta = {"generated_at": run_at, "tool_version": tool_version(), "inputs": [str(i) for i in inputs],
            "workers": workers, "scheduler": scheduler, "elapsed_s": round(time.monotonic() - t0, 3)}
    write_summary(out, ranked, pdf=pdf, meta=meta, skipped_files=skipped_files)
    for r in ranked:
        r.pop("_history", None)
    return BatchResult(rows=ranked, out_dir=out, n_files=len(files), elapsed_s=time.monotonic() - t0,
                       pdf=pdf, skipped_files=skipped_files)
