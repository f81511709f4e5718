"""One loop from record to result: identify, NARX-SP selection, data quality, [explain], severity.

`diagnose(record)` returns a `Diagnosis` (the JSON-ready result plus the objects the figures need);
`diagnose_record(record)` returns only the result dict, the object batch, monitor and demo store.

Optional stages (the NARX-SP bank, the missing-physics explanation) degrade gracefully: when one is
not installed or fails, the result carries a warning (``service.narx_unavailable``,
``service.explain_unavailable``) and the rest of the diagnosis stands. Identification itself is
required: its failure raises (a `DataError` for unusable data) and the batch records the loop as
failed.
"""

from __future__ import annotations

import functools
import importlib
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ..errors import StictionError
from ..record import LoopRecord

#: Bump when the result layout, the service's own logic or the results it computes change: it is
#: part of the input hash, so a nightly re-run after an upgrade re-diagnoses every loop.
PIPELINE_REVISION = "11"

SCHEMA = "stiction.loop/1"

#: Stiction size (S, % of span) at which the size part of the severity saturates.
S_SATURATION_PCT = 5.0
#: S below this (% of span) is reported as minor.
S_MINOR_PCT = 1.0
#: ``explain="auto"`` runs the missing-physics stage when the fit's free-run r2 on PV is below this.
EXPLAIN_AUTO_R2 = 0.5
#: A regular cycle this slow (seconds) is a daily, shift or weather pattern of the plant (ambient
#: temperature, production schedule), not a loop oscillation: a valve's stick-slip cycle is set by
#: the loop's own dynamics (seconds to an hour). It is reported as a slow cycle and not ranked.
SLOW_CYCLE_S = 4 * 3600.0


@functools.lru_cache(maxsize=1)
def tool_version() -> str:
    """The installed package version plus the pipeline revision, e.g. ``"0.1.0+p1"``."""
    try:
        from importlib.metadata import version

        v = version("stiction")
    except Exception:  # pragma: no cover - not installed
        v = "0+unknown"
    return f"{v}+p{PIPELINE_REVISION}"


@dataclass(frozen=True, eq=False)
class Diagnosis:
    """Everything one loop's report needs.

    Attributes
    ----------
    record : LoopRecord
    result : dict
        The JSON-ready result (what ``LOOP.json`` holds).
    identification : object or None
        `diagnose.identify.Identification` (its ``.fit`` gives the model path and error surface).
    selection : object or None
        `diagnose.narx.bank.Selection` of the NARX-SP model nearest to (S, J).
    narx_mv_hat_pct : array or None
        NARX-SP free-run valve position over the whole record.
    narx_pv_hat : array or None
        That valve path pushed through the fitted process model (compared with the recorded PV when
        the record has no MV).
    explanation : object or None
        `diagnose.physics.Explanation` when requested and available.
    """

    record: LoopRecord
    result: dict
    identification: Any = None
    selection: Any = None
    narx_mv_hat_pct: np.ndarray | None = None
    narx_pv_hat: np.ndarray | None = None
    explanation: Any = None
    timings_s: Mapping[str, float] = field(default_factory=dict)


def _optional(module: str) -> Any | None:
    """Import an optional stage; None when it is not installed (not when it is broken)."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (module == exc.name or module.startswith(exc.name + ".")):
            return None
        raise


@functools.lru_cache(maxsize=1)
def _bank() -> Any:
    """The NARX-SP bank, loaded once per process (None when the narx package is absent)."""
    mod = _optional("diagnose.narx.bank")
    if mod is None:
        return None
    return mod.load_bank()


def _jsonable(obj: Any) -> Any:
    """Numpy scalars/arrays and tuples into plain JSON types; NaN/inf into None."""
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    return obj


def _warning(code: str, message: str, **extra: Any) -> dict[str, Any]:
    return {"code": code, "message": message, **extra}


def _num(value: Any) -> float | None:
    try:
        f = float(value)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _interval(value: Any) -> tuple[float | None, float | None]:
    if isinstance(value, Mapping):
        return _num(value.get("lo", value.get("low"))), _num(value.get("hi", value.get("high")))
    if isinstance(value, (list, tuple)) and len(value) == 2:
        return _num(value[0]), _num(value[1])
    return None, None


def stiction_present(result: Mapping[str, Any]) -> bool | None:
    """Whether the result says the valve is sticky (None when it does not say)."""
    st = result.get("stiction")
    if isinstance(st, Mapping):
        st = st.get("present", st.get("detected", st.get("verdict")))
    if isinstance(st, bool):
        return st
    if isinstance(st, str):
        s = st.lower()
        if s in ("yes", "true", "stiction", "present", "likely", "detected"):
            return True
        if s in ("no", "false", "none", "absent", "not detected"):
            return False
        return None
    cls = str(result.get("class") or "").lower()
    if cls:
        return cls not in ("none", "no stiction", "no_stiction")
    return None


def oscillation_info(result: Mapping[str, Any]) -> dict[str, Any]:
    """Period (s), regularity/strength and whether the loop oscillates, from the result."""
    osc = result.get("oscillation") or {}
    if not isinstance(osc, Mapping):
        return {"present": None, "period_s": None, "strength": None}
    period = _num(osc.get("period_s", osc.get("period")))
    strength = None
    for key in ("regularity", "strength", "score", "power_fraction"):
        if _num(osc.get(key)) is not None:
            strength = _num(osc.get(key))
            break
    present = osc.get("present", osc.get("oscillating", osc.get("detected")))
    if not isinstance(present, bool):
        present = None if period is None else (strength is None or strength >= 0.5)
    slow = bool(present) and period is not None and period >= SLOW_CYCLE_S
    if slow:
        present = False
    return {"present": present, "period_s": period, "strength": strength, "slow_cycle": slow,
            "amplitude": _num(osc.get("amplitude", osc.get("amplitude_pv")))}


def op_in_percent(result: Mapping[str, Any]) -> bool:
    """False when identification found OP outside 0..100 % (mean-centred or in engineering units):
    S and J are then in OP's own units, not in % of valve span."""
    return not any(str(w.get("code", "")) == "op_not_percent" for w in result.get("warnings") or ())


def sj_unit(result: Mapping[str, Any]) -> str:
    """The unit S and J are in, in words."""
    return "% of valve span" if op_in_percent(result) else "in OP's own units (OP is not in % of span)"


def severity(result: Mapping[str, Any]) -> dict[str, Any]:
    """Rank score 0-100 from the probability of stiction, its size, oscillation and data quality.

    * stiction: up to 50 points, ``50 p (0.75 + 0.25 min(S / 5 %, 1))`` with ``p`` the combined
      verdict's probability of stiction (the confidence of a sticky verdict where no probability
      is given) and S taken as 0 when the valve is not sticky or its size is unknown: the
      probability orders the loops, the size breaks ties among likely sticky valves;
    * oscillation: up to 25 points when the loop oscillates, ``25 * clip(r / 2, 0.5, 1)`` with r
      Thornhill's regularity (a regular oscillation has r > 1);
    * data quality: 5 points per data-quality warning, at most 15 (a loop whose data cannot be
      trusted needs someone to look at it too);
    * robustness: 10 points when the selected NARX-SP model is not robust at this (S, J).
    """
    sticky = stiction_present(result)
    S = (_num(result.get("S")) or 0.0) if sticky else 0.0
    p = _num(result.get("stiction_probability"))
    if p is None:
        conf = _num(result.get("confidence"))
        conf = 1.0 if conf is None else min(max(conf, 0.0), 1.0)
        p = conf if sticky else 0.0
    size = 50.0 * min(max(p, 0.0), 1.0) * (0.75 + 0.25 * min(S / S_SATURATION_PCT, 1.0))
    osc = oscillation_info(result)
    if osc["present"]:
        strength = osc["strength"]  # Thornhill's regularity: > 1 regular, >= 2 very regular
        osc_pts = 25.0 * (1.0 if strength is None else min(max(strength / 2.0, 0.5), 1.0))
    else:
        osc_pts = 0.0
    dq = sum(1 for w in result.get("warnings", ()) if str(w.get("code", "")).startswith("data_quality."))
    dq_pts = min(5.0 * dq, 15.0)
    narx = result.get("narx") or {}
    rob_pts = 10.0 if isinstance(narx, Mapping) and narx.get("robust") is False else 0.0
    score = size + osc_pts + dq_pts + rob_pts
    return {"score": round(score, 2), "size": round(size, 2), "oscillation": round(osc_pts, 2),
            "data_quality": round(dq_pts, 2), "robustness": round(rob_pts, 2)}


def verdict(result: Mapping[str, Any]) -> str:
    """One line for a control engineer: sticky or not, how much, how sure."""
    sticky = stiction_present(result)
    S, J = _num(result.get("S")), _num(result.get("J"))
    conf = _num(result.get("confidence"))
    hedged = any(str(w.get("code", "")) == "data_quality.compression" for w in result.get("warnings", ()))
    sure = "" if conf is None else f" (confidence {conf:.0%})"
    if sticky is None:
        return "Inconclusive: the data did not allow a stiction verdict" + sure + "."
    if not sticky:
        return "No stiction found: the valve follows the controller output" + sure + "."
    if S is None or J is None:
        size = ""
    elif op_in_percent(result):
        size = f"S = {S:.2f} %, J = {J:.2f} % of valve span"
    else:
        size = f"S = {S:.2f}, J = {J:.2f} {sj_unit(result)}"
    word = "Possible stiction" if hedged or (conf is not None and conf < 0.5) else "Stiction"
    minor = " (minor)" if S is not None and S < S_MINOR_PCT else ""
    return f"{word}{minor}: {size}, class {result.get('class', '?')}{sure}."


def recommended_action(result: Mapping[str, Any]) -> str:
    """A plain-words next step, from the verdict, size, oscillation and data quality."""
    sticky = stiction_present(result)
    S = _num(result.get("S")) or 0.0
    J = _num(result.get("J")) or 0.0
    conf = _num(result.get("confidence"))
    osc = oscillation_info(result)
    codes = {str(w.get("code", "")) for w in result.get("warnings", ())}
    from ..plain import duration

    period = f" with a period of {duration(osc['period_s'])}" if osc["period_s"] else ""
    pct = op_in_percent(result)
    span = " % of its span" if pct else " (in OP's own units: OP is not in % of span)"
    parts: list[str] = []
    if "data_quality.compression" in codes:
        parts.append("The historian data look compressed, which can fake stiction: export the "
                     "loop again with compression off (or raw archive values) before acting.")
    if sticky is None:
        parts.append("Collect a longer record in automatic mode with the loop moving (a few "
                     "set-point steps help) and run the diagnosis again.")
    elif sticky and (conf is None or conf >= 0.5) and S >= S_MINOR_PCT:
        parts.append(f"Have the valve inspected at the next opportunity: it sticks by about {S:.1f}{span}"
                     f"{' and jumps by ' + format(J, '.1f') + (' %' if pct else '') if J >= 0.05 else ''}. Check the "
                     "packing (over-tightened or worn), the actuator and the positioner.")
        if osc["present"]:
            parts.append(f"Until then the stick-slip cycle{period} can be eased by reducing the "
                         "controller's integral action (longer integral time) or by a stiction "
                         "compensator; do not simply raise the gain.")
    elif sticky:
        parts.append(f"Stiction is small or uncertain (S about {S:.1f}{span}): keep the loop on "
                     "the watch list and compare with the next nightly run before acting.")
    else:
        if osc["present"]:
            parts.append(f"The loop oscillates{period} but the valve is not the cause: check the "
                         "controller tuning and look for an oscillating disturbance upstream.")
        else:
            parts.append("No action needed on the valve.")
    if osc.get("slow_cycle"):
        parts.append(f"PV follows a slow cycle{period} (a daily or shift pattern of the plant, not a "
                     "loop oscillation); it is not counted in the ranking.")
    if any(c.startswith("data_quality.") for c in codes - {"data_quality.compression"}):
        parts.append("See the data-quality warnings: they limit how far this result can be trusted.")
    return " ".join(parts)


def _identify(record: LoopRecord, **opts: Any) -> Any:
    from ..identify import identify  # required stage

    return identify(record, **opts)


def select_narx(result: Mapping[str, Any]) -> tuple[Any, dict[str, Any] | None]:
    """The NARX-SP bank model for an identification result, and its ``robustness...`` warning.

    Returns ``(None, None)`` when the loop has no stiction (no bank model describes a healthy
    valve). Raises when the bank cannot be loaded; callers decide how to degrade.
    """
    S, J = _num(result.get("S")), _num(result.get("J"))
    if S is None or J is None or not result.get("stiction"):
        return None, None
    bank = _bank()
    if bank is None:
        raise ModuleNotFoundError("the NARX-SP bank (diagnose.narx) is not installed")
    sel = bank.select(S, J)
    return sel, sel.warning()


def _narx_stage(record: LoopRecord, ident: Any, result: dict, warns: list) -> tuple[Any, Any, Any]:
    try:
        sel, warning = select_narx(result)
    except Exception as exc:  # a broken or missing bank must not sink the diagnosis
        warns.append(_warning("service.narx_unavailable", f"the NARX-SP bank could not be used: {exc}"))
        return None, None, None
    if sel is None:
        return None, None, None
    result["narx"] = _jsonable(sel.to_dict())
    if warning:
        warns.append(dict(warning))
    try:
        mv_hat = np.asarray(_bank().free_run(sel, record.op), dtype=float)
    except Exception as exc:
        warns.append(_warning("service.narx_failed", f"NARX-SP free run failed: {exc}"))
        return sel, None, None
    pv_hat = None
    fit = getattr(ident, "fit", None)
    if fit is not None and getattr(fit, "process", None) is not None:
        try:
            pv_hat = np.asarray(fit.process.simulate(mv_hat, record.ts_s), dtype=float)
        except Exception:  # the figure just omits the PV comparison
            pv_hat = None
    target = record.mv if record.mv is not None else None
    if target is not None and target.shape == mv_hat.shape:
        result["narx"]["free_run_rmse_record"] = _num(np.sqrt(np.mean((mv_hat - target) ** 2)))
        result["narx"]["free_run_against"] = "mv"
    elif pv_hat is not None and pv_hat.shape == record.pv.shape:
        result["narx"]["free_run_rmse_record"] = _num(np.sqrt(np.mean((pv_hat - record.pv) ** 2)))
        result["narx"]["free_run_against"] = "pv"
    return sel, mv_hat, pv_hat


def _explain_stage(record: LoopRecord, result: dict, warns: list) -> Any:
    mod = _optional("diagnose.physics")
    if mod is None or not hasattr(mod, "explain"):
        warns.append(_warning("service.explain_unavailable",
                              "the missing-physics stage is not installed; no explanation section"))
        return None
    try:
        expl = mod.explain(record)
    except StictionError as exc:
        warns.append(_warning("service.explain_failed", f"missing-physics explanation failed: {exc}"))
        return None
    except Exception as exc:
        warns.append(_warning("service.explain_failed",
                              f"missing-physics explanation failed ({type(exc).__name__}: {exc})"))
        return None
    result["explanation"] = _jsonable(expl.to_dict())
    return expl


def _explain_wanted(ident: Any, result: Mapping[str, Any]) -> tuple[bool, str]:
    """``explain="auto"``: run the missing-physics stage only where the model leaves a mismatch.

    The stage costs several times the identification, so a nightly batch runs it where it has
    something to explain: the Hammerstein fit's free-run r2 on PV is below `EXPLAIN_AUTO_R2`, or
    identification warned of a poor fit.
    """
    fit = getattr(ident, "fit", None)
    r2 = _num(getattr(fit, "r2", None)) if fit is not None else _num((result.get("fit") or {}).get("r2"))
    if any(w.get("code") == "poor_fit" for w in result.get("warnings") or ()):
        return True, "identification warned of a poor fit"
    if r2 is None:
        return True, "no fit quality to judge by"
    if r2 < EXPLAIN_AUTO_R2:
        return True, f"the fitted model explains {r2:.0%} of PV (< {EXPLAIN_AUTO_R2:.0%})"
    return False, f"the fitted model explains {r2:.0%} of PV: no mismatch worth explaining"


def _record_info(record: LoopRecord) -> dict[str, Any]:
    return {"n": record.n, "ts_s": record.ts_s, "duration_s": record.duration_s, "start": record.start,
            "roles": sorted(record.roles()), "source": record.source,
            "segment": record.meta.get("segment"), "n_segments": record.meta.get("n_segments"),
            "format": record.meta.get("format")}


def diagnose(record: LoopRecord, *, explain: bool | str = False, narx: bool = True,
             identify_options: Mapping[str, Any] | None = None) -> Diagnosis:
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
        Passed to `diagnose.identify.identify`.

    Raises
    ------
    StictionError
        When identification fails (unusable data); optional stages only add warnings.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ident = _identify(record, **dict(identify_options or {}))
    timings["identify"] = time.perf_counter() - t0
    result: dict[str, Any] = _jsonable(ident.to_dict())
    warns: list[dict[str, Any]] = list(result.get("warnings") or [])
    known = {(w.get("code"), w.get("message")) for w in warns}
    for w in caught:
        code = f"runtime.{w.category.__name__}"
        msg = str(w.message)
        if (code, msg) not in known and not any(m == msg for _, m in known):
            warns.append(_warning(code, msg))
            known.add((code, msg))
    result.setdefault("loop", record.name)
    result.setdefault("data_quality", [f.to_dict() for f in record.findings])
    t1 = time.perf_counter()
    sel = mv_hat = pv_hat = None
    if narx:
        sel, mv_hat, pv_hat = _narx_stage(record, ident, result, warns)
    timings["narx"] = time.perf_counter() - t1
    expl = None
    if explain == "auto":
        explain, why = _explain_wanted(ident, result)
        result["explain_auto"] = why
    if explain:
        t2 = time.perf_counter()
        expl = _explain_stage(record, result, warns)
        timings["explain"] = time.perf_counter() - t2
    result.setdefault("narx", None)
    result.setdefault("explanation", None)
    result["warnings"] = _jsonable(warns)
    result["record"] = _jsonable(_record_info(record))
    result["severity"] = severity(result)
    result["verdict"] = verdict(result)
    result["action"] = recommended_action(result)
    result["schema"] = SCHEMA
    result["tool_version"] = tool_version()
    result["timings_s"] = {k: round(v, 4) for k, v in timings.items()}
    return Diagnosis(record=record, result=result, identification=ident, selection=sel,
                     narx_mv_hat_pct=mv_hat, narx_pv_hat=pv_hat, explanation=expl, timings_s=timings)


def diagnose_record(record: LoopRecord, *, explain: bool | str = False, **options: Any) -> dict:
    """The JSON-ready result of `diagnose` (the contract batch, monitor and demo use)."""
    return diagnose(record, explain=explain, **options).result
