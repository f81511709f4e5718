"""From parsed series to loop records: roles, tag maps, uniform grid, segments, findings."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from diagnose.errors import ConnectorError, DataError, ShortRecordError
from diagnose.record import Finding, LoopRecord

from .columns import FRAME_LABEL, option, role_of, split_tag
from .layouts import Series, Table
from .tagmap import TagMap
from .timebase import (END_TOLERANCE, Cleaned, clean_series, empty_slots, estimate_period, irregularity, iso_utc,
                       hold_grid, jittered_period, runs, shared_rows, spread_truncated, to_grid)

ROLES = ("op", "pv", "sp", "mv", "mode")
DEFAULT_MIN_SAMPLES = 20
DEFAULT_MAX_GAP_SAMPLES = 10
#: Records are cut to their newest this many samples for diagnosis (``max_samples``; 0: no limit).
DEFAULT_MAX_SAMPLES = 100_000
#: Largest grid a loop may need (points where OP and PV have data), about 160 MB per signal.
MAX_GRID_SAMPLES = 20_000_000
_MANUAL_TEXT = {"man", "manual", "m", "oos", "iman", "lo", "local", "hand", "h", "off"}
_AUTO_TEXT = {"auto", "a", "cas", "cascade", "rcas", "rout", "aut", "automatic", "remote", "on"}
_MODE_TEXT = {**{t: 0.0 for t in _MANUAL_TEXT}, **{t: 1.0 for t in _AUTO_TEXT}}


@dataclass
class LoopSpec:
    name: str
    roles: dict[str, Series]
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    mode_auto: tuple[float, ...] | None = None
    table: Table | None = None
    #: tags of the same file with an OP or a PV column but not both: no loop, said on every record
    left_out: dict[str, str] = field(default_factory=dict)


def _loop_name_for_bare(table: Table, options: dict) -> str:
    if options.get("name"):
        return str(options["name"])
    if table.label and not table.label.startswith("<"):
        return Path(table.label).stem
    return "LOOP"


def _columns_hint(table: Table) -> str:
    cols = table.raw_columns or [s.name for s in table.series]
    shown = ", ".join(cols[:12]) + (" ..." if len(cols) > 12 else "")
    return shown


def specs_from_table(table: Table, options: dict, tagmap: TagMap | None) -> list[LoopSpec]:
    """Which series make which loops in one file."""
    by_name = {s.name: s for s in table.series}
    by_lower = {s.name.lower(): s for s in table.series}
    # a column named by a number (op=0 for a frame's column 0) is given too: only None or "" is not
    overrides = {r: options[r] for r in ("op", "pv", "sp", "mv", "mode") if options.get(r) not in (None, "")}
    if isinstance(options.get("ts"), str):
        _check_time_column(options["ts"], overrides, table.label)
    if tagmap is not None and not overrides:
        specs = []
        for lm in tagmap.loops.values():
            if lm.roles["op"].tag.lower() not in by_lower or lm.roles["pv"].tag.lower() not in by_lower:
                continue
            sp = LoopSpec(lm.name, {})
            for role, rm in lm.roles.items():
                s = by_lower.get(rm.tag.lower())
                if s is None:
                    continue
                _claim(sp.roles, role, s, table.label)
                if rm.range is not None:
                    sp.ranges[role] = rm.range
                if rm.units:
                    sp.units[role] = rm.units
                if role == "mode":
                    sp.mode_auto = rm.auto
            sp.table = table
            specs.append(sp)
        return specs
    if overrides:
        roles: dict[str, Series] = {}
        for role, col in overrides.items():
            s = by_name.get(col) or by_lower.get(str(col).lower())
            if s is None:
                raise ConnectorError(f"no column named {col!r} for {role.upper()} (columns: {_columns_hint(table)})",
                                     path=table.label)
            _claim(roles, role, s, table.label)
        for role in ("op", "pv"):
            if role not in roles:
                # take the naming rule's column for the missing role, from the same tag if possible
                tag = split_tag(next(iter(roles.values())).name)[0]
                cands = [s for s in table.series if role_of(s.name) == role and s not in roles.values()]
                same = [s for s in cands if split_tag(s.name)[0] == tag] or cands
                if len(same) != 1:
                    # the naming rule's column may be the very one given for another role
                    taken = next(((r, t) for r, t in roles.items() if role_of(t.name) == role
                                  and split_tag(t.name)[0] == tag), None)
                    if taken is not None:
                        raise ConnectorError(
                            f"column {taken[1].name!r} looks like {role.upper()} but is given for "
                            f"{taken[0].upper()} ({option('--' + taken[0], table.label)}), which leaves "
                            f"{role.upper()} without a column; give the {taken[0].upper()} column there, or "
                            f"name {role.upper()} with {option('--' + role, table.label)}",
                            path=table.label)
                    raise ConnectorError(f"no {role.upper()} column found (columns: {_columns_hint(table)}); "
                                         f"name it with {option('--' + role, table.label)}", path=table.label)
                roles[role] = same[0]
        tag = split_tag(roles["op"].name)[0] or split_tag(roles["pv"].name)[0]
        for role in ("sp", "mv", "mode"):
            if role not in roles:
                same = [s for s in table.series if role_of(s.name) == role and split_tag(s.name)[0] == tag]
                if len(same) == 1:
                    roles[role] = same[0]
        name = options.get("name") or tag or _loop_name_for_bare(table, options)
        return [LoopSpec(str(name), roles, table=table)]
    groups: dict[str, dict[str, Series]] = {}
    for s in table.series:
        role = role_of(s.name)
        if role is None or role == "time":
            continue
        tag = split_tag(s.name)[0]
        g = groups.setdefault(tag, {})
        if role in g:
            raise ConnectorError(f"columns {g[role].name!r} and {s.name!r} both look like {role.upper()}; "
                                 f"choose one with {option('--' + role, table.label)}", path=table.label)
        g[role] = s
    # a bare loop missing a role: take a unique column starting with the role word ("PV_flow_t_h")
    bare = groups.get("")
    if bare is not None:
        for role in ("op", "pv"):
            if role in bare:
                continue
            cands = [s for s in table.series if role_of(s.name) is None and s.name.lower().startswith(role + "_")]
            if len(cands) == 1:
                bare[role] = cands[0]
    specs = []
    left_out = {}
    for tag, g in groups.items():
        if "op" in g and "pv" in g:
            name = tag or _loop_name_for_bare(table, options)
            specs.append(LoopSpec(name, g, table=table))
        elif ("op" in g or "pv" in g) and tag:
            left_out[tag] = "PV" if "op" in g else "OP"
    for sp in specs:
        sp.left_out = left_out
    if not specs:
        have = {r for g in groups.values() for r in g}
        missing = [r.upper() for r in ("op", "pv") if r not in have] or ["OP+PV of one tag"]
        raise ConnectorError(f"no {' or '.join(missing)} column found (columns: {_columns_hint(table)}); "
                             f"{_name_columns(table.label)}" + _isa_hint(table), path=table.label)
    if len(specs) == 1 and options.get("name"):
        specs[0].name = str(options["name"])
    return specs


def _check_time_column(col: str, overrides: dict, label: str | None) -> None:
    """A signal given as the time vanishes from the loop: say so, not "no PV column found" (or
    nothing at all, for a stem position read as time stamps)."""
    opt = option("--time", label)
    given = next((r for r, c in overrides.items() if str(c).lower() == col.lower()), None)
    if given is not None:
        raise ConnectorError(f"column {col!r} is given for both the time ({opt}) and {given.upper()}; "
                             "each role needs its own column", path=label)
    role = role_of(col)
    if role not in (None, "time"):
        raise ConnectorError(f"column {col!r} given as the time ({opt}) is named as a loop's {role.upper()}; "
                             f"give the time column, or leave {opt} out to find it by its name or content",
                             path=label)


def _claim(roles: dict[str, Series], role: str, s: Series, label: str | None) -> None:
    """Give column ``s`` the role; one column for two roles would diagnose a signal against itself."""
    other = next((r for r, taken in roles.items() if taken is s), None)
    if other is not None:
        raise ConnectorError(f"column {s.name!r} is given for both {other.upper()} and {role.upper()}; "
                             "each role needs its own column", path=label)
    roles[role] = s


_ISA = re.compile(r"^([A-Za-z])([VTvt])[-_]?(\w+)$")


def _isa_hint(table: Table) -> str:
    """``FV_211`` (valve) and ``FT_211`` (transmitter) of one loop: suggest them as OP and PV."""
    found: dict[tuple[str, str], dict[str, str]] = {}
    for s in table.series:
        m = _ISA.match(s.name.strip())
        if m:
            found.setdefault((m.group(1).upper(), m.group(3)), {})[m.group(2).upper()] = s.name
    for pair in found.values():
        if "V" in pair and "T" in pair:
            if table.label == FRAME_LABEL:
                example = f"op={pair['V']!r}, pv={pair['T']!r}"
            else:
                example = f"--op {pair['V']} --pv {pair['T']}"
            return f" (for example {example}, if {pair['V']} is the valve output in %)"
    return ""


def _name_columns(label: str | None) -> str:
    """What to do when the naming rule finds no OP or PV: name them (a tag map is for files only)."""
    if label == FRAME_LABEL:
        return "name the columns with op=, pv="
    return "name the columns with --op/--pv or give a tag map with --tags"


def _joined_blank(a: Series, b: Series) -> np.ndarray | None:
    """The empty-cell mask of two series joined end to end (None when neither had an empty cell)."""
    if a.blank is None and b.blank is None:
        return None
    return np.concatenate([a.blank if a.blank is not None else np.zeros(a.x.size, bool),
                           b.blank if b.blank is not None else np.zeros(b.x.size, bool)])


def _mode_values(s: Series, auto: tuple[float, ...] | None) -> np.ndarray:
    """1 = automatic, 0 = manual, NaN = unknown, from numbers or text states."""
    x = s.x
    out = np.where(np.isfinite(x), 1.0, np.nan)
    fin = np.isfinite(x)
    if auto is not None:
        out[fin] = np.isin(x[fin], np.asarray(auto)).astype(float)
    else:
        out[fin] = (x[fin] != 0).astype(float)
    if s.n_text and s.cells is not None:
        codes, uniq = pd.factorize(s.cells)
        state = np.array([_MODE_TEXT.get(u.strip().lower(), np.nan) if isinstance(u, str) else np.nan
                          for u in uniq] + [np.nan])
        known = np.isfinite(state[codes])
        out[known] = state[codes][known]
    return out


_SCHEME_RULES = {"opc": "as OPC codes, good at 192-255", "ip21_status": "as IP.21 status, good at 0",
                 "phd_confidence": "as PHD confidence, good at 50-100", "text": "as text, good when 'Good'",
                 "wincc_validity": "as WinCC validity, good at 1"}


def _no_values(s: Series, table: Table | None = None) -> str | None:
    """What a signal without a single usable value holds instead (None when it has one)."""
    if np.isfinite(s.x).any():
        return None
    if s.n_text and s.n_text + s.n_blank >= s.x.size:
        return f"only text values (e.g. {s.examples[0]!r})" if s.examples else "only text values"
    if s.n_bad_quality:
        meta = table.meta if table is not None else {}
        rule = _SCHEME_RULES.get(str(meta.get("quality_scheme")).split("+")[0])
        column = s.quality_column or meta.get("quality_column")
        if column and rule:
            # every row bad is more often a quality scheme read the wrong way than a dead tag
            return (f"no value with good quality (column {column!r} read {rule}); if the "
                    "export's quality codes mean something else, delete that column")
        return "no value with good quality"
    if s.n_nonfinite:
        return "only NaN/inf values"
    return "no numeric values"


def _bad_finding(role: str, s: Series, n_rows: int) -> Finding | None:
    n_bad = s.n_text + s.n_nonfinite + s.n_bad_quality
    if n_bad == 0:
        return None
    frac = n_bad / max(1, n_rows)
    parts = []
    if s.n_text:
        parts.append(f"{s.n_text} text states" + (f" ({', '.join(repr(e) for e in s.examples[:3])})"
                                                   if s.examples else ""))
    if s.n_nonfinite:
        parts.append(f"{s.n_nonfinite} NaN/inf")
    if s.n_bad_quality:
        parts.append(f"{s.n_bad_quality} with bad quality codes")
    return Finding("bad_values", f"{role.upper()} column {s.name!r}: {'; '.join(parts)} turned into gaps",
                   "warning" if frac > 0.01 else "info",
                   {"role": role, "column": s.name, "text": s.n_text, "nonfinite": s.n_nonfinite,
                    "bad_quality": s.n_bad_quality, "examples": list(s.examples[:3]), "frac": round(frac, 4)})


#: A value this many times the signal's robust range (1st to 99th percentile) beyond that range,
#: and (`OUTLIER_SIZES`) far beyond the signal's own size, is no measurement: a spike, an overflow
#: or a historian's sentinel for a bad value (-9999, 1e30).
OUTLIER_RANGES = 5.0
#: ... more than this many times max(|median|, robust range, 1) from the median. A plant's own
#: extremes (a trip to 0, OP saturated at 100 %, a derivative kick) stay within a few times the
#: signal's size; overflows and sentinels lie orders of magnitude beyond it.
OUTLIER_SIZES = 50.0
#: At most this share of a signal's samples may be called outliers; more is the signal's own spread.
OUTLIER_MAX_SHARE = 0.01
#: Historians' and DCSs' bad-value sentinels: a run of exactly one of these values more than
#: `OUTLIER_RANGES` robust ranges outside the signal's range is no measurement even where it is not
#: `OUTLIER_SIZES` times the signal's size (-9999 on a flow of thousands, -999 on a level in %).
SENTINELS = (-999.0, -9999.0, -99999.0, -999999.0)


#: A run of far values at most this long that returns to the signal's range is a spike.
SPIKE_MAX_SAMPLES = 3


def gross_outliers(x: np.ndarray) -> np.ndarray:
    """Mask of the values of ``x`` that are no measurement: runs of values more than
    `OUTLIER_RANGES` robust ranges outside its 1st to 99th percentile and either more than
    `OUTLIER_SIZES` times the signal's size from its median or a known sentinel (`SENTINELS`),
    with the signal back in range on both sides, that are either spikes (at most
    `SPIKE_MAX_SAMPLES` long) or one value repeated (a sentinel). A longer excursion that varies,
    or one the record starts or ends in, may be the plant's own and is kept. Nothing is flagged in a
    signal that is flat over that range (a step off a flat line is a change, not an outlier) or
    where more than `OUTLIER_MAX_SHARE` would be."""
    x = np.asarray(x, dtype=float)
    out = np.zeros(x.shape, bool)
    fin = np.isfinite(x)
    if np.count_nonzero(fin) < 20:
        return out
    lo, hi = np.percentile(x[fin], [1.0, 99.0])
    width = hi - lo
    if not width > 1e-12 * max(1.0, abs(hi), abs(lo)):
        return out
    med = float(np.median(x[fin]))
    size = max(abs(med), width, 1.0)
    with np.errstate(invalid="ignore"):
        far = fin & ((x < lo - OUTLIER_RANGES * width) | (x > hi + OUTLIER_RANGES * width)) \
            & ((np.abs(x - med) > OUTLIER_SIZES * size) | np.isin(x, SENTINELS))
    if not far.any() or np.count_nonzero(far) > OUTLIER_MAX_SHARE * np.count_nonzero(fin):
        return out
    edges = np.flatnonzero(np.diff(np.concatenate([[0], far.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2]):
        back_in_range = a > 0 and b < x.shape[0]
        if back_in_range and (b - a <= SPIKE_MAX_SAMPLES or np.all(x[a:b] == x[a])):
            out[a:b] = True
    return out


def _outlier_finding(role: str, c: Cleaned, far: np.ndarray, absolute: bool) -> Finding:
    k = int(np.count_nonzero(far))
    i = int(np.flatnonzero(far)[0])
    first = iso_utc(float(c.t[i])) if absolute else f"t = {float(c.t[i]):g} s"
    return Finding("outliers", f"{role.upper()} has {k} value{'s' if k != 1 else ''} far outside its range (the "
                   f"first {c.x[i]:.6g} at {first}): a spike, overflow or bad-value sentinel, read as a bad value "
                   "and filled like a gap", "warning",
                   {"role": role, "count": k, "first_value": float(c.x[i]), "first_at": first})


def _date_order_finding(guess: dict, label: str | None) -> Finding:
    """The dates read alike day first and month first (``05/03/2026`` ... on one day): how they were
    read, and the option that says which it is. A guess, not a fact, so a warning: read the
    wrong way a loop's record is put on another day (or months away from its neighbours)."""
    day_first = guess["read"] == "day first"
    other = "month" if day_first else "day"
    if label == FRAME_LABEL:
        where, what = f"the frame's time column {guess.get('column')!r}", "column"
        fix = f"dayfirst={not day_first}"
    else:
        where, what = str(label), "file"
        fix = ("--monthfirst" if day_first else "--dayfirst") + f" (dayfirst={not day_first} in Python)"
    return Finding("date_order", f"{where}: the date order is ambiguous: in dates such as {guess['example']!r} "
                   "every day and month is 12 or less, and the two readings span the same time, so the "
                   f"{what} cannot say which comes first; they were read {guess['read']} ({guess['date']}); "
                   f"if the {other} comes first, give {fix}", "warning",
                   {"read": guess["read"], "example": guess["example"], "date": guess["date"],
                    "source": None if label == FRAME_LABEL else label, "option": fix})


#: Share of rows sharing their time stamp above which the stamps are taken as truncated. A file
#: joined from overlapping exports or a few repeated rows stays far below it; seconds dropped
#: from data sampled every 50 s or faster put at least a third of the rows in shared stamps
#: (every row below 30 s).
TRUNCATED_SHARE = 0.2


def build_records(spec: LoopSpec, options: dict) -> list[LoopRecord]:
    """One record per contiguous segment of one loop."""
    table = spec.table
    label = table.label if table else None
    min_samples = int(options.get("min_samples") or DEFAULT_MIN_SAMPLES)
    max_samples = int(options.get("max_samples", DEFAULT_MAX_SAMPLES) or 0)
    if 0 < max_samples < min_samples:
        raise ConnectorError(f"max_samples (--max-samples) is {max_samples}, below the shortest record of "
                             f"{min_samples} samples; give {min_samples} or more, or 0 to keep every sample",
                             path=label)
    findings: list[Finding] = []
    if spec.left_out:
        # a loop missing a role is not diagnosed; it would otherwise vanish from a batch unremarked
        tags = ", ".join(f"{t} (no {role})" for t, role in sorted(spec.left_out.items()))
        findings.append(Finding("loop_left_out", f"not diagnosed from this file, for want of a column: {tags}; "
                                f"{_name_columns(label)}", "info",
                                {"tags": dict(sorted(spec.left_out.items()))}))
    cleaned = {}
    ts_opt = options.get("ts_s")
    n_dups = 0
    shared = 0.0           # the largest share of OP's or PV's rows in runs of one time stamp
    spread_rows = 0
    reversed_any = False
    # A PV with no usable value at all (a dead transmitter, a tag exported as bad) does not stop
    # the loop: OP's own shape can still be judged (diagnose.evidence.op_shape). A flat stand-in
    # PV on OP's samples marks it unusable for the diagnosis, and a finding says why.
    pv_s, op_s = spec.roles["pv"], spec.roles["op"]
    pv_dead = _no_values(pv_s, table) if _no_values(op_s) is None else None
    if pv_dead is not None:
        findings.append(Finding("pv_missing", f"PV column {pv_s.name!r} has {pv_dead}: the loop is judged "
                                "without PV, from OP alone (and the stem position where recorded)", "warning",
                                {"column": pv_s.name}))
    for role, s in spec.roles.items():
        if role == "pv" and pv_dead is not None:
            s = Series(s.name, op_s.t, np.where(np.isfinite(op_s.x), 0.0, np.nan), first_line=s.first_line)
        elif role in ("op", "pv") and (what := _no_values(s, table)) is not None:
            raise ConnectorError(f"{role.upper()} column has {what}; nothing to diagnose",
                                 path=label, line=s.first_line, column=s.name)
        t = s.t
        if t is None:
            if not ts_opt:
                where = "a DatetimeIndex or a time column" if label == FRAME_LABEL else "a time column"
                raise ConnectorError(f"no time column; give the sample period with {option('--ts-s', label, 'SECONDS')} "
                                     f"or add {where}", path=label)
            t = np.arange(s.x.size) * float(ts_opt)
        x = _mode_values(s, spec.mode_auto) if role == "mode" else s.x
        t = np.asarray(t, float)
        if ts_opt and s.t is not None and (spread := spread_truncated(t, float(ts_opt))) is not None:
            spread_rows = max(spread_rows, shared_rows(t))
            t = spread
        if role == "mode" and s.blank is not None and s.blank.size == t.size:
            # an empty cell of a mode column is no event (a mode archived on change, exported beside
            # tags sampled at every row): the state before it holds; a bad value makes it unknown
            t, x = t[~s.blank], x[~s.blank]
        c = clean_series(t, x)
        n_dups = max(n_dups, c.n_duplicates)
        if role in ("op", "pv") and t.size:
            shared = max(shared, c.n_shared / max(1, int(np.count_nonzero(np.isfinite(t)))))
        reversed_any |= c.reversed
        if role in ("op", "pv", "mv") and not (role == "pv" and pv_dead is not None):
            far = gross_outliers(c.x)
            if far.any():
                findings.append(_outlier_finding(role, c, far, bool(table and table.absolute)))
                c = replace(c, x=np.where(far, np.nan, c.x))
        cleaned[role] = c
    if spread_rows:
        findings.append(Finding("duplicates", f"{spread_rows} rows shared their time stamp in equal runs (time "
                                f"stamps truncated, e.g. seconds dropped by a spreadsheet); they were spread in "
                                f"file order at the given {float(ts_opt):g} s", "info",
                                {"count": 0, "spread": spread_rows}))
    if n_dups and shared >= TRUNCATED_SHARE:
        res = next((f" to whole {u}" for u, q in (("minutes", 60.0), ("seconds", 1.0))
                    if all(np.all(np.mod(c.t, q) == 0) for r, c in cleaned.items() if r in ("op", "pv"))), "")
        findings.append(Finding(
            "duplicates", f"{n_dups} duplicated timestamps: {100 * shared:.0f} % of the rows share their time stamp "
            f"with the row before or after, so the time stamps look truncated{res} (e.g. seconds dropped by a spreadsheet). "
            "Only the first row of each time stamp was kept, and the period was read from what was left; "
            "re-export with full time stamps, or, if the rows are evenly spaced in time order, give "
            f"{option('--ts-s', label, 'SECONDS')} (equal runs of rows per time stamp are then spread in file "
            "order at that period)",
            "warning", {"count": n_dups, "share": round(shared, 4)}))
    elif n_dups:
        findings.append(Finding("duplicates", f"{n_dups} duplicated timestamps; the first value of each was kept",
                                "info", {"count": n_dups}))
    back = next((c.clock_back_s for r, c in cleaned.items() if r in ("op", "pv") and c.clock_back_s is not None), None)
    # only naive times read as UTC can hide a clock change that --tz would undo: times with an offset,
    # epoch numbers or times already read in a zone stepping back are something else
    wall_clock = (table is not None and table.meta.get("time_zone") == "UTC" and not options.get("tz")
                  and table.meta.get("time_format") not in ("epoch_s", "epoch_ms"))
    if back is not None and wall_clock:
        at = iso_utc(back).replace("T", " ").rstrip("Z")
        findings.append(Finding(
            "clock_back", f"the time stamps step back by up to an hour once, after {at}, as a local clock does "
            "when daylight saving time ends: read without their time zone, the repeated stretch overlaps the "
            "stretch before it, its rows were dropped as duplicates and the record is spliced there; give "
            f"{option('--tz', label)} with the plant's time zone (e.g. {option('--tz', label, 'Europe/Berlin')}) "
            "to read them in order",
            "warning", {"after": at}))
    guess = table.meta.get("date_order_guessed") if table is not None else None
    if guess:
        findings.append(_date_order_finding(guess, label))
    ts_s = float(ts_opt) if ts_opt else (table.ts_s if table and table.ts_s else None)
    jitter = None
    if ts_s is None:
        ts_s = estimate_period([cleaned["op"].t, cleaned["pv"].t])
        jitter = jittered_period([cleaned["op"].t, cleaned["pv"].t], ts_s)
        if jitter is not None:
            ts_s = jitter.ts_s
    if not (np.isfinite(ts_s) and ts_s > 0):
        raise ConnectorError("cannot tell the sample period (fewer than two distinct times); give "
                             f"{option('--ts-s', label, 'SECONDS')}", path=label)
    max_gap_s = float(options.get("max_gap_s") or DEFAULT_MAX_GAP_SAMPLES * ts_s)
    # a max_gap_s given is the limit for every tag; a mode is a state, not a line between archive points
    spacing = {r: _spacing(c) for r, c in cleaned.items()}
    densest = min(spacing["op"], spacing["pv"])
    gap_of = {r: max_gap_s if options.get("max_gap_s") or r == "mode" else
              _archive_gap(c, spacing[r], densest, max_gap_s) for r, c in cleaned.items()}
    starts = [c.t[np.isfinite(c.x)][0] for r, c in cleaned.items() if r in ("op", "pv")]
    ends = [c.t[np.isfinite(c.x)][-1] for r, c in cleaned.items() if r in ("op", "pv")]
    t0, t1 = max(starts), min(ends)
    if t1 < t0:
        raise ConnectorError("OP and PV do not overlap in time", path=label)
    n_grid = int(np.floor((t1 - t0) / ts_s + END_TOLERANCE)) + 1
    # The grid is uniform from t0 at ts_s, but only its points near OP or PV samples are built:
    # a stray row far from the rest costs a point, not the span between.
    spans = _grid_spans(cleaned["op"], cleaned["pv"], t0, ts_s, n_grid, gap_of["op"], gap_of["pv"])
    n_points = int((spans[:, 1] - spans[:, 0] + 1).sum())
    if n_points > MAX_GRID_SAMPLES:
        raise ConnectorError(f"{n_points} samples at {ts_s:g} s is too many (the limit is {MAX_GRID_SAMPLES}); "
                             f"give a larger {option('--ts-s', label)}", path=label)
    gk = _grid_index(spans)
    grid = t0 + gk * ts_s
    step = float((t0 + ts_s) - t0) if n_grid > 1 else max_gap_s
    # a compressed OP is irregular by design (the compression finding says so): PV tells the sampling
    sampled = "pv" if spacing["op"] > 1.5 * densest else "op"
    irr = irregularity(cleaned[sampled].t, ts_s, max_gap_s)
    own_s = estimate_period([cleaned[sampled].t]) if ts_opt else float("nan")
    if ts_opt and np.isfinite(own_s) and irregularity(cleaned[sampled].t, own_s, max_gap_s) <= 0.05 \
            and abs(own_s - ts_s) > 0.1 * ts_s:
        # evenly spaced times at another period than the one given: the user's period, not the
        # data, made the grid differ, and "irregular sampling" would blame the data
        findings.append(Finding("resampled", f"the times are evenly spaced at {own_s:g} s, but the period given "
                                f"({option('--ts-s', label)}) is {ts_s:g} s: the record was resampled to {ts_s:g} s "
                                f"by linear interpolation{' (no anti-alias filter)' if ts_s > own_s else ''}; leave "
                                f"{option('--ts-s', label)} out to keep the data's own period", "warning",
                                {"data_ts_s": own_s, "ts_s": ts_s}))
    elif irr > 0.05:
        findings.append(Finding("irregular_sampling", f"{100 * irr:.0f} % of sample intervals differ from "
                                f"{ts_s:g} s by more than 10 %; resampled to a uniform {ts_s:g} s grid",
                                "info" if irr < 0.3 else "warning", {"frac": round(irr, 4), "ts_s": ts_s}))
    gridded: dict[str, np.ndarray] = {}
    filled = np.zeros(grid.shape, bool)
    for role, c in cleaned.items():
        g, filled_here = to_grid(c.t, c.x, grid, gap_of[role], step=step, bad_gap_s=max_gap_s)
        gridded[role] = g
        own = estimate_period([c.t])
        if role in ("op", "pv") and jitter is not None:
            filled[_nearest(grid, empty_slots(c.t, c.x, jitter))] = True
        elif role in ("op", "pv") and not (own > 1.5 * ts_s):  # sparser archives are not gaps
            filled |= filled_here
        s = spec.roles[role]
        if role != "mode" and not (role == "pv" and pv_dead is not None):
            f = _bad_finding(role, s, s.x.size)
            if f:
                findings.append(f)
    for role in ("op", "mv"):
        if role in gridded and role in spec.ranges:
            lo, hi = spec.ranges[role]
            gridded[role] = 100.0 * (gridded[role] - lo) / (hi - lo)
    ok = np.isfinite(gridded["op"]) & np.isfinite(gridded["pv"])
    segs = _split_at_jumps(runs(ok), gk)
    first_ok = gk.size > 0 and gk[0] == 0 and ok[0]
    last_ok = gk.size > 0 and gk[-1] == n_grid - 1 and ok[-1]
    long_gaps = max(0, len(segs) - 1) + int(not first_ok) + int(not last_ok) if segs else 0
    filled_total = int(np.count_nonzero(filled & ok))   # points left in a long gap are in no record
    if filled_total:
        findings.append(Finding("gap", f"{filled_total} samples where OP or PV was missing or bad (in gaps up "
                                f"to {max_gap_s:g} s) were filled by linear interpolation",
                                "info" if filled_total < 0.01 * n_grid else "warning",
                                {"filled": filled_total, "max_gap_s": max_gap_s}))
    usable = [(a, b) for a, b in segs if b - a >= min_samples]
    dropped = len(segs) - len(usable)
    far = _isolated(segs, usable, grid, bool(table and table.absolute))
    if far:
        findings.append(far)
    if not usable:
        best = max((b - a for a, b in segs), default=0)
        # where unreadable cells made the gaps, say which (decimal commas in a frame's text column,
        # a tag exported as text): the count alone sends the user looking for missing rows
        why = next((f for f in findings if f.code == "bad_values" and f.data.get("frac", 0) > 0.5
                    and f.data.get("role") in ("op", "pv")), None)
        said = (f"; {why.data['role'].upper()} column {why.data['column']!r} is mostly unreadable "
                f"({why.message.split(': ', 1)[-1]})" if why is not None else "")
        raise ShortRecordError(f"too few samples: the longest stretch without a gap has {best} sample{'' if best == 1 else 's'} "
                               f"(need at least {min_samples}){said}", path=label)
    if len(segs) > 1 or long_gaps:
        gap_s = [float(grid[segs[i + 1][0]] - grid[segs[i][1] - 1]) for i in range(len(segs) - 1)]
        findings.append(Finding("segment", f"split into {len(usable)} segment(s) at gaps longer than "
                                f"{max_gap_s:g} s (longest gap {max(gap_s, default=0):g} s"
                                + (f"; {dropped} stretch(es) under {min_samples} samples dropped" if dropped else "")
                                + "); each segment is a record of its own (identify takes the longest, "
                                "batch diagnoses each)",
                                "warning", {"segments": len(usable), "dropped": dropped,
                                            "gaps_s": [round(g, 3) for g in gap_s][:50],
                                            "max_gap_s": max_gap_s}))
    op_all = gridded["op"][ok]
    if not spec.ranges.get("op") and op_all.size and (np.min(op_all) < -5 or np.max(op_all) > 105):
        findings.append(Finding("op_range", f"OP ranges from {np.min(op_all):.4g} to {np.max(op_all):.4g}, "
                                "outside 0-100 %; if it is in engineering units "
                                + ("scale it to % of span" if label == FRAME_LABEL else "give its range in a tag map"),
                                "warning", {"min": float(np.min(op_all)), "max": float(np.max(op_all))}))
    window = _window(usable, max_samples, min_samples, ts_s)
    progress = options.get("_progress")
    if progress:
        total = sum(b - a for a, b in usable)
        progress.say(f"{spec.name}: {total} samples at {ts_s:g} s in {len(usable)} segment(s)"
                     + (f"; {window.message}" if window else ""))
    if window is not None:
        usable = window.segments
    from diagnose.quality import assess

    meta_base: dict[str, Any] = dict(table.meta if table else {})
    meta_base.pop("dates", None)   # the dates a folder's files pooled for their order: said by time_format
    meta_base.update({"columns": {r: s.name for r, s in spec.roles.items()},
                      "order": "newest_first" if cleaned["op"].reversed else "oldest_first",
                      "absolute_time": bool(table.absolute) if table else False,
                      "tz": options.get("tz") or ("UTC" if table and table.absolute else None),
                      "dst": options.get("dst", "infer"), "max_gap_s": max_gap_s,
                      "n_segments": len(usable), "quality_checked": True})
    units = {"op": "%", "mv": "%"}
    units.update({k: s.units for k, s in spec.roles.items() if k in ("pv", "sp") and s.units})
    units.update({k: v for k, v in spec.units.items() if k in ("pv", "sp")})
    mode = None
    if "mode" in spec.roles:
        # a state holds between its events (a mode archived on change): no ramp, no gap limit
        mode = hold_grid(cleaned["mode"].t, cleaned["mode"].x, grid, step=step)
    records = []
    for i, (a, b) in enumerate(usable):
        roles = {}
        extra: list[Finding] = [window.finding] if window else []
        for role in ("sp", "mv"):
            if role not in gridded:
                continue
            v = gridded[role][a:b]
            fin = np.isfinite(v)
            if fin.all():
                roles[role] = v
            elif fin.mean() >= 0.9:
                idx = np.arange(v.size)
                roles[role] = np.interp(idx, idx[fin], v[fin])
            else:
                extra.append(Finding("gap", f"{role.upper()} has {int((~fin).sum())} missing samples in this "
                                     "segment and was left out", "info", {"role": role}))
        meta = dict(meta_base)
        meta["segment"] = i
        meta["segment_samples"] = [int(gk[a]), int(gk[b - 1]) + 1]
        if mode is not None:
            m = mode[a:b]
            manual = np.isfinite(m) & (m < 0.5)
            meta["manual_intervals"] = [[int(x), int(y)] for x, y in runs(manual)]
            # before the mode's first sample, or after a bad one, the state is not known
            meta["mode_unknown_intervals"] = [[int(x), int(y)] for x, y in runs(~np.isfinite(m))]
            meta["has_mode"] = True
        start = iso_utc(float(grid[a])) if (table and table.absolute) else None
        try:
            rec = LoopRecord(name=spec.name, ts_s=ts_s, op=gridded["op"][a:b], pv=gridded["pv"][a:b],
                             sp=roles.get("sp"), mv=roles.get("mv"), start=start, units=units,
                             ranges={k: v for k, v in spec.ranges.items() if k in ("op", "mv", "pv", "sp")},
                             findings=tuple(findings + extra), source=label, meta=meta)
        except DataError as exc:  # pragma: no cover - arrays are finite by construction
            raise ConnectorError(str(exc), path=label) from None
        records.append(rec.with_findings(*assess(rec)))
    return records


def _grid_spans(op: Cleaned, pv: Cleaned, t0: float, ts_s: float, n_grid: int, op_gap_s: float,
                pv_gap_s: float) -> np.ndarray:
    """``[lo, hi]`` ranges of grid indices ``k`` (points ``t0 + k ts_s``) within reach of OP or PV
    data, shape (m, 2), sorted and disjoint.

    A point is within reach of a signal where `to_grid` can give it a value: inside a stretch of
    samples without a gap longer than that signal's gap limit, or within the on-sample tolerance of a sample
    (spare points on each side cover it). Elsewhere both would be NaN, so those points are not
    built; points that only one signal reaches are, so that its interpolated samples are counted.
    """
    tol = 1e-9 + 1e-6 * max(1.0, (abs(t0) + n_grid * ts_s) * 1e-6)
    margin = 1 + int(np.ceil(tol / ts_s))

    def spans(c: Cleaned, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
        t = c.t[np.isfinite(c.x)]
        brk = np.flatnonzero(np.diff(t) > max_gap_s * (1 + 1e-9))
        first = np.concatenate(([0], brk + 1))
        last = np.concatenate((brk, [t.size - 1]))
        lo = np.clip(np.floor((t[first] - t0) / ts_s) - margin, 0, n_grid - 1).astype(np.int64)
        hi = np.clip(np.ceil((t[last] - t0) / ts_s) + margin, 0, n_grid - 1).astype(np.int64)
        return lo, hi

    (lo_a, hi_a), (lo_b, hi_b) = spans(op, op_gap_s), spans(pv, pv_gap_s)
    lo, hi = np.concatenate((lo_a, lo_b)), np.concatenate((hi_a, hi_b))
    order = np.argsort(lo, kind="stable")
    return _merge(lo[order], hi[order])


def _nearest(grid: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the grid point nearest each time."""
    if not times.size or not grid.size:
        return np.empty(0, np.int64)
    j = np.clip(np.searchsorted(grid, times), 1, max(1, grid.size - 1))
    left = np.maximum(j - 1, 0)
    right = np.minimum(j, grid.size - 1)
    return np.where(np.abs(times - grid[left]) <= np.abs(grid[right] - times), left, right)


def _spacing(c: Cleaned) -> float:
    """Median spacing of a tag's archive points (its values, bad ones left out)."""
    return estimate_period([c.t[np.isfinite(c.x)]])


def _archive_gap(c: Cleaned, spacing_s: float, densest_s: float, max_gap_s: float) -> float:
    """The longest gap interpolated in one tag, whose median archive spacing is ``spacing_s``
    (`_spacing`).

    A tag archived more sparsely than the denser of OP and PV (at a slower rate, or by exception
    as historians compress: irregular points, far apart where the value ran straight) is a line
    between its archive points. Its limit is `DEFAULT_MAX_GAP_SAMPLES` of its own mean archive
    spacing, so that only a silence far longer than usual for that tag is a gap; when OP and PV
    are both silent, the denser one's gap splits the record anyway.
    """
    t = c.t[np.isfinite(c.x)]
    if t.size < 2 or not spacing_s > 1.5 * densest_s:
        return max_gap_s
    return max(max_gap_s, DEFAULT_MAX_GAP_SAMPLES * float(t[-1] - t[0]) / (t.size - 1))


def _grid_index(spans: np.ndarray) -> np.ndarray:
    """All indices of ``[lo, hi]`` ranges, in order."""
    counts = spans[:, 1] - spans[:, 0] + 1
    offsets = np.cumsum(counts) - counts
    return np.arange(int(counts.sum()), dtype=np.int64) + np.repeat(spans[:, 0] - offsets, counts)


def _merge(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Sorted, possibly overlapping ``[lo, hi]`` ranges joined into disjoint ones, shape (m, 2)."""
    if not lo.size:
        return np.zeros((0, 2), np.int64)
    start = np.concatenate(([True], lo[1:] > np.maximum.accumulate(hi)[:-1]))
    first = np.flatnonzero(start)
    return np.stack([lo[first], np.maximum.reduceat(hi, first)], axis=1)


def _split_at_jumps(segs: list[tuple[int, int]], k: np.ndarray) -> list[tuple[int, int]]:
    """Runs of a sparse grid split where the grid skips points (a run never spans skipped points)."""
    jumps = np.flatnonzero(np.diff(k) != 1) + 1
    if not jumps.size:
        return segs
    out = []
    for a, b in segs:
        cuts = jumps[np.searchsorted(jumps, a, side="right"):np.searchsorted(jumps, b, side="left")].tolist()
        edges = [a] + cuts + [b]
        out.extend(zip(edges[:-1], edges[1:]))
    return out


#: A stretch this far (seconds) from the rest of a loop's data is reported as isolated.
ISOLATED_GAP_S = 86_400.0


def _isolated(segs: list[tuple[int, int]], usable: list[tuple[int, int]], grid: np.ndarray,
              absolute: bool) -> Finding | None:
    """Short stretches (dropped) lying more than `ISOLATED_GAP_S` from every usable segment."""
    if not usable or len(segs) == len(usable):
        return None
    starts = np.array([grid[a] for a, _ in usable])
    ends = np.array([grid[b - 1] for _, b in usable])
    kept = set(usable)
    far = []
    for a, b in segs:
        if (a, b) in kept:
            continue
        dist = float(np.min(np.maximum(starts - grid[b - 1], grid[a] - ends)))
        if dist > ISOLATED_GAP_S:
            far.append((a, b, dist))
    if not far:
        return None
    n = sum(b - a for a, b, _ in far)
    worst = max(d for _, _, d in far)
    when = (lambda t: iso_utc(t)) if absolute else (lambda t: f"t = {t:g} s")
    where = ", ".join(f"{b - a} at {when(grid[a])}" for a, b, _ in far[:3]) + (" ..." if len(far) > 3 else "")
    return Finding("isolated", f"{n} sample(s) far from the rest of the record ({where}; up to "
                   f"{_duration(worst)} away) were left out: too few to diagnose on their own",
                   "warning", {"stretches": len(far), "samples": n, "max_distance_s": round(worst, 3),
                               "starts_s": [round(float(grid[a]), 3) for a, _, _ in far[:50]]})


def _duration(seconds: float) -> str:
    """A duration in the unit an engineer would say it in."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


@dataclass(frozen=True)
class _Window:
    """The newest ``max_samples`` samples of a loop: the segments kept and the finding that says so."""

    segments: list[tuple[int, int]]
    finding: Finding
    message: str


def _window(usable: list[tuple[int, int]], max_samples: int, min_samples: int, ts_s: float) -> _Window | None:
    total = sum(b - a for a, b in usable)
    if max_samples <= 0 or total <= max_samples:
        return None
    kept: list[tuple[int, int]] = []
    left = max_samples
    for a, b in reversed(usable):
        if left < min_samples:
            break
        start = max(a, b - left)
        kept.append((start, b))
        left -= b - start
    kept.reverse()
    n = sum(b - a for a, b in kept)
    message = (f"diagnosing the newest {n} ({_duration(n * ts_s)}) of {total} samples "
               f"({_duration(total * ts_s)}): the max_samples limit")
    finding = Finding("window", f"the record has {total} usable samples ({_duration(total * ts_s)}); only the "
                      f"newest {n} ({_duration(n * ts_s)}) are diagnosed (max_samples = {max_samples}; a larger "
                      "limit costs time and memory)", "info",
                      {"samples": total, "kept": n, "max_samples": max_samples})
    return _Window(kept, finding, message)


def _joined_units(loop: str, role: str, b: Series, s: Series, base: LoopSpec, sp: LoopSpec) -> str | None:
    """The units of a signal joined from two files (header brackets or a units row): the one both
    give, or the one a file gives; units that differ are an error naming both files, since values
    in m3/h and l/s joined into one record would read as a step that the valve never made."""
    if b.units and s.units and b.units.strip().lower() != s.units.strip().lower():
        first = base.table.label if base.table else "?"
        raise ConnectorError(f"loop {loop}: its {role.upper()} is in {b.units!r} in {first} (column {b.column!r}) "
                             f"but in {s.units!r} in {sp.table.label} (column {s.column!r}); the files cannot be "
                             "joined into one record: convert one of them, or read the files one by one")
    return b.units or s.units


def merge_specs(specs: list[LoopSpec]) -> list[LoopSpec]:
    """Join the same loop found in several files (absolute times only) into one spec."""
    out: dict[str, LoopSpec] = {}
    order: list[str] = []
    for sp in specs:
        key = sp.name
        if key in out and sp.table is not None and sp.table.absolute and out[key].table.absolute \
                and set(sp.roles) == set(out[key].roles):
            base = out[key]
            for role, s in sp.roles.items():
                b = base.roles[role]
                base.roles[role] = Series(b.name, np.concatenate([b.t, s.t]), np.concatenate([b.x, s.x]),
                                          b.n_text + s.n_text, b.n_nonfinite + s.n_nonfinite,
                                          b.n_bad_quality + s.n_bad_quality, b.n_blank + s.n_blank,
                                          (b.examples + s.examples)[:4], b.first_line, b.column,
                                          None, units=_joined_units(sp.name, role, b, s, base, sp),
                                          quality_column=b.quality_column or s.quality_column,
                                          blank=_joined_blank(b, s))
            continue
        if key in out:
            key = f"{sp.name}@{os.path.basename(sp.table.label) if sp.table else len(order)}"
        out[key] = sp
        order.append(key)
    return [out[k] for k in order]
