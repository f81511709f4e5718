"""One loop from record to result: identify, NARX-SP selection, [explain], severity, verdict, action.

`diagnose(record)` returns a `Diagnosis`: every typed object a report needs (the identification,
the NARX-SP selection and free run, the explanation, the severity, the verdict in words, the
recommended action, timings). ``Diagnosis.to_dict()`` is what ``LOOP.json`` holds; reports,
batch, monitor, history and metrics read the objects.

Optional stages (the NARX-SP bank, the missing-physics explanation) degrade gracefully: when one is
not installed or fails, the diagnosis carries a warning (``service.narx_unavailable``,
``service.explain_unavailable``...) and the rest stands. Identification itself is required: its
failure raises (a `DataError` for unusable data) and the batch records the loop as failed.
"""

from __future__ import annotations

import functools
import html
import importlib
import math
import time
import warnings as pywarnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..errors import StictionError
from ..identification import SLOW_CYCLE_S, Identification
from ..notes import Note
from ..record import LoopRecord

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..narx.bank import Bank, Selection
    from ..physics import Explanation

#: Bump when the result layout, the service's own logic or the results it computes change: it is
#: part of the input hash, so a nightly re-run after an upgrade re-diagnoses every loop.
PIPELINE_REVISION = "13"

#: The layout of ``LOOP.json``. Results of every schema in `READ_SCHEMAS` are read back (history,
#: batch resume); ``/2`` added ``summary`` (the plant summary's row), ``source`` and typed warnings.
SCHEMA = "stiction.loop/2"
READ_SCHEMAS = ("stiction.loop/1", "stiction.loop/2")

#: Stiction size (S, % of span) at which the size part of the severity saturates.
S_SATURATION_PCT = 5.0
#: S below this (% of span) is reported as minor.
S_MINOR_PCT = 1.0
#: ``explain="auto"`` runs the missing-physics stage when the fit's free-run r2 on PV is below this.
EXPLAIN_AUTO_R2 = 0.5

__all__ = ["Diagnosis", "NarxRun", "Severity", "diagnose", "assemble", "select_narx", "severity",
           "verdict_text", "recommended_action", "sj_unit", "tool_version", "SCHEMA", "PIPELINE_REVISION",
           "SLOW_CYCLE_S"]


@functools.lru_cache(maxsize=1)
def tool_version() -> str:
    """The installed package version plus the pipeline revision, e.g. ``"0.1.0+p1"``."""
    try:
        from importlib.metadata import version

        v = version("stiction")
    except Exception:  # pragma: no cover - not installed
        v = "0+unknown"
    return f"{v}+p{PIPELINE_REVISION}"


def _num(value: float | None) -> float | None:
    if value is None:
        return None
    f = float(value)
    return f if math.isfinite(f) else None


def _jsonable(obj: Any) -> Any:
    """Numpy scalars/arrays and tuples into plain JSON types; NaN/inf into None (for the
    explanation's own `to_dict`, which comes from another package)."""
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj


# ------------------------------------------------------------------------------------------------
# results


@dataclass(frozen=True)
class Severity:
    """The rank score of a loop, 0-100, and its parts (see `severity`)."""

    score: float
    size: float
    oscillation: float
    data_quality: float

    def to_dict(self) -> dict[str, float]:
        return {"score": self.score, "size": self.size, "oscillation": self.oscillation,
                "data_quality": self.data_quality}


@dataclass(frozen=True, eq=False)
class NarxRun:
    """The selected NARX-SP model's free run over the record.

    Attributes
    ----------
    mv_hat_pct : array or None
        The model's valve position over the whole record, in OP's own units (% of span for an OP
        in %; the bank's models run in % and the result is scaled back); None: the free run failed.
    pv_hat : array or None
        That valve path through the fitted process model.
    rmse_record : float or None
        RMS difference from the recorded MV (or, without MV, of ``pv_hat`` from the recorded PV).
    against : {"mv", "pv"} or None
        What ``rmse_record`` compares with.
    """

    mv_hat_pct: np.ndarray | None = field(default=None, repr=False)
    pv_hat: np.ndarray | None = field(default=None, repr=False)
    rmse_record: float | None = None
    against: str | None = None


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Everything one loop's report needs.

    Attributes
    ----------
    record : LoopRecord
    identification : Identification
        With its NARX-SP selection (``identification.narx``).
    narx_run : NarxRun or None
        The selected model's free run over the record.
    explanation : diagnose.physics.Explanation or None
        When the missing-physics stage ran.
    explain_auto : str or None
        Why ``explain="auto"`` ran the stage or not.
    warnings : tuple of Note
        Every warning: the identification's, runtime warnings, the optional stages'.
    severity : Severity
    verdict_text : str
        One sentence for a control engineer.
    action : str
        The recommended next step, in plain words.
    timings_s : mapping of str to float
        Seconds per stage (``identify``, ``narx``, ``explain``, and in the batch ``report``).
    tool_version : str
    loop_id, input_hash, window, degradation : str or None
        Set by the batch and the monitor: the report name, the input hash the result is filed
        under, the monitor window, and the history's degradation warning.
    sticky_runs : (int, int) or None
        Set by the batch from the history: how many of the loop's last runs (this one included)
        said stiction, and how many were counted (`diagnose.service.history.sticky_runs`).
    """

    record: LoopRecord
    identification: Identification
    severity: Severity
    verdict_text: str
    action: str
    warnings: tuple[Note, ...] = ()
    narx_run: NarxRun | None = None
    explanation: Explanation | None = None
    explain_auto: str | None = None
    timings_s: Mapping[str, float] = field(default_factory=dict)
    tool_version: str = ""
    loop_id: str | None = None
    input_hash: str | None = None
    window: str | None = None
    degradation: str | None = None
    sticky_runs: tuple[int, int] | None = None

    @property
    def loop(self) -> str:
        return self.identification.loop

    @property
    def selection(self) -> Selection | None:
        return self.identification.narx

    @property
    def narx_mv_hat_pct(self) -> np.ndarray | None:
        return None if self.narx_run is None else self.narx_run.mv_hat_pct

    @property
    def narx_pv_hat(self) -> np.ndarray | None:
        return None if self.narx_run is None else self.narx_run.pv_hat

    def record_info(self) -> dict[str, Any]:
        rec = self.record
        return {"n": rec.n, "ts_s": rec.ts_s, "duration_s": rec.duration_s, "start": rec.start,
                "roles": sorted(rec.roles()), "source": rec.source,
                "segment": rec.meta.get("segment"), "n_segments": rec.meta.get("n_segments"),
                "format": rec.meta.get("format"), "data_hash": rec.data_hash()}

    def to_dict(self) -> dict[str, Any]:
        """The JSON object ``LOOP.json`` holds (`SCHEMA`)."""
        d = self.identification.to_dict()
        narx = d.get("narx")
        if narx is not None and self.narx_run is not None:
            narx["free_run_rmse_record"] = _num(self.narx_run.rmse_record)
            narx["free_run_against"] = self.narx_run.against
        d["explanation"] = None if self.explanation is None else _jsonable(self.explanation.to_dict())
        if self.explain_auto is not None:
            d["explain_auto"] = self.explain_auto
        d["warnings"] = [w.to_dict() for w in self.warnings]
        d["record"] = _jsonable(self.record_info())
        d["severity"] = self.severity.to_dict()
        d["verdict"] = self.verdict_text
        d["action"] = self.action
        d["schema"] = SCHEMA
        d["tool_version"] = self.tool_version
        d["timings_s"] = {k: round(float(v), 4) for k, v in self.timings_s.items()}
        for key in ("loop_id", "input_hash", "window", "degradation"):
            value = getattr(self, key)
            if value is not None:
                d[key] = value
        if self.sticky_runs is not None:
            d["sticky_runs"] = list(self.sticky_runs)
        return d

    # ------------------------------------------------------------------ notebooks
    def __repr__(self) -> str:
        return (f"Diagnosis(loop={self.loop!r}, verdict={self.verdict_text!r}, severity={self.severity.score:g}, "
                f"warnings={len(self.warnings)})")

    def _repr_html_(self) -> str:
        e = html.escape
        return (f"<div><p><strong>{e(self.verdict_text)}</strong></p><p>{e(self.action)}</p>"
                f"<p>Severity {self.severity.score:.0f} of 100.</p>{self.identification._repr_html_()}</div>")

    def plot(self, kind: str = "trends") -> Figure:
        """The report's figure as a new matplotlib `Figure`: ``trends``, ``phase``, ``surface``,
        ``spectrum`` (see `Identification.plot`) or ``narx`` (the NARX-SP free run)."""
        if kind != "narx":
            return self.identification.plot(kind)
        from .. import figures
        from ..errors import DataError

        if self.narx_mv_hat_pct is None:
            raise DataError(f"{self.loop}: no NARX-SP free run (no stiction, or the stage did not run)")
        return figures.draw_narx(figures.new_figure("narx"), self.record, self.narx_mv_hat_pct, self.narx_pv_hat,
                                 op_units=self.identification.op_units)


# ------------------------------------------------------------------------------------------------
# plain words


def sj_unit(ident: Identification) -> str:
    """The unit S and J are in, in words (`Identification.sj_units_text`)."""
    return ident.sj_units_text


#: data-quality warnings the severity does not count
_UNSCORED_FINDINGS = frozenset({"data_quality.date_order"})


def severity(ident: Identification, warnings: Sequence[Note] = ()) -> Severity:
    """Rank score on a 0-100 scale (the parts add up to at most 90) from the probability of
    stiction, its size, oscillation and data quality.

    * stiction: up to 50 points, ``50 p (0.75 + 0.25 min(S / 5 %, 1))`` with ``p`` the combined
      verdict's probability of stiction (the confidence of a sticky verdict where no probability
      is given) and S taken as 0 when the valve is not sticky or its size is unknown: the
      probability orders the loops, the size breaks ties among likely sticky valves;
    * oscillation: up to 25 points when the loop oscillates (a slow cycle does not count),
      ``25 * clip(r / 2, 0.5, 1)`` with r Thornhill's regularity (a regular oscillation has r > 1);
    * data quality: 5 points per data-quality warning, at most 15 (a loop whose data cannot be
      trusted needs someone to look at it too); an ambiguous date order is not counted.

    Whether the selected NARX-SP model is robust at this (S, J) adds nothing: it says how well the
    tool's model bank covers the valve, not how bad the valve is.
    """
    sticky = ident.stiction
    S = (ident.S_pct or 0.0) * ident.pct_per_op_unit if sticky else 0.0
    p = ident.stiction_probability
    if p is None:
        p = min(max(ident.confidence, 0.0), 1.0) if sticky else 0.0
    size = 50.0 * min(max(p, 0.0), 1.0) * (0.75 + 0.25 * min(S / S_SATURATION_PCT, 1.0))
    if ident.loop_oscillates:
        osc_pts = 25.0 * min(max(ident.oscillation.regularity / 2.0, 0.5), 1.0)
    else:
        osc_pts = 0.0
    # an ambiguous date order dates the record (the history's order), it does not spoil the samples
    dq = sum(1 for w in warnings if w.code.startswith("data_quality.") and w.code not in _UNSCORED_FINDINGS)
    dq_pts = min(5.0 * dq, 15.0)
    score = size + osc_pts + dq_pts
    # to the 0.1 every report shows: loops that look tied are tied, and the ranking orders them by S
    return Severity(round(score, 1), round(size, 1), round(osc_pts, 1), round(dq_pts, 1))


def verdict_text(ident: Identification, warnings: Sequence[Note] = ()) -> str:
    """One line for a control engineer: sticky or not, how much, how sure."""
    from ..plain import percent

    conf = ident.confidence
    hedged = any(w.code == "data_quality.compression" for w in warnings)
    sure = f" (confidence {percent(conf)})"
    if ident.nothing_judged:
        return ("No evidence either way: no test could judge this record, so the valve may or may not "
                "stick; see the warnings for what the data lack.")
    if not ident.stiction and ident.method == "op_only":
        return "No stiction found from OP's shape alone (PV is unusable)" + sure + "."
    if not ident.stiction:
        return "No stiction found: the valve follows the controller output" + sure + "."
    S, J = ident.S_pct, ident.J_pct
    if ident.valve_not_moving and ident.fitted_S_pct is not None:
        # the class is "unknown" because it was not judged: say why, and the bound S has
        unit = f" {sj_unit(ident)}"
        return (f"Stiction: the valve never moved while OP travelled {ident.fitted_S_pct:.2f}{unit}, so S is "
                f"at least that; J and the class are not judged{sure}.")
    if S is None or J is None:
        size = "size unknown"
    elif ident.op_in_percent:
        size = f"S = {S:.2f} %, J = {J:.2f} % of valve span"
    else:
        d = ident.sj_digits
        size = f"S = {S:.{d}f}, J = {J:.{d}f} {sj_unit(ident)}"
    word = "Possible stiction" if hedged or conf < 0.5 else "Stiction"
    minor = " (minor)" if S is not None and S * ident.pct_per_op_unit < S_MINOR_PCT else ""
    return f"{word}{minor}: {size}, class {ident.cls}{sure}."


def recommended_action(ident: Identification, warnings: Sequence[Note] = (),
                       sticky_runs: tuple[int, int] | None = None) -> str:
    """A plain-words next step, from the verdict, size, oscillation and data quality, and (in the
    batch) how many of the loop's last runs said stiction (``sticky_runs``: k of m, this run
    included)."""
    from ..plain import duration

    S = ident.S_pct or 0.0
    J = ident.J_pct or 0.0
    k = ident.pct_per_op_unit          # S and J in OP's units; the thresholds are in % of span
    d = ident.sj_digits - 1            # a tenth of a per cent either way
    conf = ident.confidence
    codes = {w.code for w in warnings}
    period_s = ident.oscillation.period_s
    period = f" with a period of {duration(period_s)}" if period_s else ""
    pct = ident.op_in_percent
    span = " % of its span" if pct else f" ({sj_unit(ident)})"
    # a valve called sticky on at least half of three or more recent runs: a habit, not one window
    habit = None
    if sticky_runs is not None and sticky_runs[1] >= 3 and 2 * sticky_runs[0] >= sticky_runs[1]:
        habit = f"the loop was called sticky in {sticky_runs[0]} of its last {sticky_runs[1]} runs"
    parts: list[str] = []
    if "data_quality.compression" in codes:
        parts.append("The historian data look compressed, which can fake stiction: export the "
                     "loop again with compression off (or raw archive values) before acting.")
    if ident.stiction and ident.valve_not_moving:
        parts.append("The recorded stem position never moved while the controller output travelled: check "
                     "that the valve is not stuck or isolated (and that the MV tag is the stem position), "
                     "then stroke-test it; J and the class need a record in which the valve moves.")
    elif ident.stiction and ident.S_pct is None:
        parts.append("The evidence says the valve sticks but its size could not be measured: have the "
                     "valve stroke-tested (or record the stem position) at the next opportunity.")
    elif ident.stiction and conf >= 0.5 and S * k >= S_MINOR_PCT:
        jump = f" and jumps by {J:.{d}f}{' %' if pct else ''}" if J * k >= 0.05 else ""
        parts.append(f"Have the valve inspected at the next opportunity: it sticks by about {S:.{d}f}{span}"
                     f"{jump}. Check the packing (over-tightened or worn), the actuator and the positioner.")
        if ident.loop_oscillates:
            parts.append(f"Until then the stick-slip cycle{period} can be eased by reducing the "
                         "controller's integral action (longer integral time) or by a stiction "
                         "compensator; do not simply raise the gain.")
    elif ident.stiction and habit:
        parts.append(f"Stiction is small or uncertain in this run (S about {S:.{d}f}{span}), but {habit}: "
                     "have the valve stroke-tested at the next opportunity.")
    elif ident.stiction:
        parts.append(f"Stiction is small or uncertain (S about {S:.{d}f}{span}): keep the loop on "
                     "the watch list and compare with the next nightly run before acting.")
    elif habit:
        parts.append(f"This run shows no stiction, but {habit}: keep the valve on the watch list (one "
                     "window can hold too little stick-slip to tell).")
    elif ident.loop_oscillates:
        parts.append(f"The loop oscillates{period} but the valve is not the cause: check the "
                     "controller tuning and look for an oscillating disturbance upstream.")
    else:
        parts.append("No action needed on the valve.")
    if ident.slow_cycle:
        parts.append(f"PV follows a slow cycle{period} (a daily or shift pattern of the plant, not a "
                     "loop oscillation); it is not counted in the ranking.")
    if any(c.startswith("data_quality.") for c in codes - {"data_quality.compression"}):
        parts.append("See the data-quality warnings: they limit how far this result can be trusted.")
    return " ".join(parts)


# ------------------------------------------------------------------------------------------------
# stages


def _optional(module: str) -> Any | None:
    """Import an optional stage; None when it is not installed (not when it is broken)."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            return None
        raise


@functools.lru_cache(maxsize=1)
def _bank() -> Bank | None:
    """The NARX-SP bank, loaded once per process (None when the narx package is absent)."""
    mod = _optional("diagnose.narx.bank")
    if mod is None:
        return None
    return mod.load_bank()


def select_narx(ident: Identification) -> tuple[Selection | None, Note | None]:
    """The NARX-SP bank model for an identification, and its ``robustness...`` warning.

    Returns ``(None, None)`` when the loop has no stiction or its size is unknown (no bank model
    describes a healthy valve). Raises when the bank cannot be loaded; callers decide how to
    degrade.
    """
    S, J = ident.S_pct, ident.J_pct
    if S is None or J is None or not ident.stiction:
        return None, None
    bank = _bank()
    if bank is None:
        raise ModuleNotFoundError("the NARX-SP bank (diagnose.narx) is not installed")
    k = ident.pct_per_op_unit     # the bank's models are in % of span
    sel = bank.select(S * k, J * k)
    return sel, sel.warning()


def _narx_stage(record: LoopRecord, ident: Identification,
                notes: list[Note]) -> tuple[Selection | None, NarxRun | None]:
    try:
        sel, warning = select_narx(ident)
    except Exception as exc:  # a broken or missing bank must not sink the diagnosis
        notes.append(Note("service.narx_unavailable", f"the NARX-SP bank could not be used: {exc}"))
        return None, None
    if sel is None:
        return None, None
    if warning is not None:
        notes.append(warning)
    try:
        bank = _bank()
        assert bank is not None
        # the bank's models take OP in % of span; the stem comes back in OP's own units
        k = ident.pct_per_op_unit
        mv_hat = np.asarray(bank.free_run(sel, record.op * k), dtype=float) / k
    except Exception as exc:
        notes.append(Note("service.narx_failed", f"NARX-SP free run failed: {exc}"))
        return sel, NarxRun()
    pv_hat = None
    if ident.fit is not None:
        try:
            pv_hat = np.asarray(ident.fit.process.simulate(mv_hat, record.ts_s), dtype=float)
        except Exception:  # the figure just omits the PV comparison
            pv_hat = None
    rmse = against = None
    if record.mv is not None and record.mv.shape == mv_hat.shape:
        rmse, against = _num(np.sqrt(np.mean((mv_hat - record.mv) ** 2))), "mv"
    elif pv_hat is not None and pv_hat.shape == record.pv.shape:
        rmse, against = _num(np.sqrt(np.mean((pv_hat - record.pv) ** 2))), "pv"
    return sel, NarxRun(mv_hat, pv_hat, rmse, against)


def _explain_stage(record: LoopRecord, notes: list[Note], threads: int | None = None) -> Explanation | None:
    mod = _optional("diagnose.physics")
    if mod is None or not hasattr(mod, "explain"):
        notes.append(Note("service.explain_unavailable",
                          "the missing-physics stage is not installed; no explanation section"))
        return None
    try:
        return mod.explain(record, threads=threads)
    except StictionError as exc:
        notes.append(Note("service.explain_failed", f"missing-physics explanation failed: {exc}"))
    except Exception as exc:
        notes.append(Note("service.explain_failed",
                          f"missing-physics explanation failed ({type(exc).__name__}: {exc})"))
    return None


def _explain_wanted(ident: Identification) -> tuple[bool, str]:
    """``explain="auto"``: run the missing-physics stage only where the model leaves a mismatch.

    The stage costs several times the identification, so a nightly batch runs it where it has
    something to explain: the Hammerstein fit's free-run r2 on PV is below `EXPLAIN_AUTO_R2`, or
    identification warned of a poor fit.
    """
    r2 = _num(ident.fit.r2) if ident.fit is not None else _num(ident.r2)
    if any(w.code == "poor_fit" for w in ident.warnings):
        return True, "identification warned of a poor fit"
    if r2 is None:
        return True, "no fit quality to judge by"
    if r2 < EXPLAIN_AUTO_R2:
        return True, f"the fitted model explains {r2:.0%} of PV (< {EXPLAIN_AUTO_R2:.0%})"
    return False, f"the fitted model explains {r2:.0%} of PV: no mismatch worth explaining"


def assemble(record: LoopRecord, ident: Identification, *, notes: Sequence[Note] = (),
             narx_run: NarxRun | None = None, explanation: Explanation | None = None,
             explain_auto: str | None = None, timings_s: Mapping[str, float] | None = None) -> Diagnosis:
    """A `Diagnosis` from its parts: severity, verdict and action follow from the identification
    (with its NARX-SP selection) and every warning (the identification's plus ``notes``)."""
    warns = tuple(dict.fromkeys(tuple(ident.warnings) + tuple(notes)))
    return Diagnosis(record=record, identification=ident, severity=severity(ident, warns),
                     verdict_text=verdict_text(ident, warns), action=recommended_action(ident, warns),
                     warnings=warns, narx_run=narx_run, explanation=explanation, explain_auto=explain_auto,
                     timings_s=dict(timings_s or {}), tool_version=tool_version())


def diagnose(record: LoopRecord, *, explain: bool | str = False, narx: bool = True,
             identify_options: Mapping[str, Any] | None = None, threads: int | None = None) -> Diagnosis:
    """Diagnose one loop: everything a report needs.

    Parameters
    ----------
    record : LoopRecord
    explain : bool or "auto"
        Run the missing-physics stage (`diagnose.physics.explain`) when it is installed; ``"auto"``
        only where the identified model leaves a mismatch (see `_explain_wanted`).
    narx : bool
        Select the NARX-SP model nearest to the identified (S, J) and free-run it over the record.
    identify_options : mapping, optional
        Passed to `diagnose.identification.identify`.
    threads : int, optional
        Threads the identification and the missing-physics stage may use (None: the cores the
        process may use). A caller that diagnoses several loops at once passes its share of the
        cores, so that loops x threads does not oversubscribe the machine; results do not depend
        on it.

    Raises
    ------
    StictionError
        When identification fails (unusable data); optional stages only add warnings.
    """
    from ..identification import identify

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    with pywarnings.catch_warnings(record=True) as caught:
        pywarnings.simplefilter("always")
        opts = dict(identify_options or {})
        if threads is not None:
            opts.setdefault("threads", threads)
        ident = identify(record, **opts)
    if ident.record is not None:
        # the record as identified (OP logged as a fraction is scaled to % by the stem position):
        # the NARX-SP run, the missing physics and the report's figures read the same OP
        record = ident.record
    timings["identify"] = time.perf_counter() - t0
    notes: list[Note] = []
    known = {w.message for w in ident.warnings}
    for w in caught:
        msg = str(w.message)
        if msg not in known:
            notes.append(Note(f"runtime.{w.category.__name__}", msg))
            known.add(msg)
    t1 = time.perf_counter()
    run = None
    if narx:
        sel, run = _narx_stage(record, ident, notes)
        ident = replace(ident, narx=sel)
    timings["narx"] = time.perf_counter() - t1
    expl = None
    why = None
    if explain == "auto":
        explain, why = _explain_wanted(ident)
    if explain:
        t2 = time.perf_counter()
        expl = _explain_stage(record, notes, threads)
        timings["explain"] = time.perf_counter() - t2
    return assemble(record, ident, notes=notes, narx_run=run, explanation=expl, explain_auto=why,
                    timings_s=timings)
