"""The baseline each stage starts from: the fitting stage's model, the identification a caller
already has, given parameters, or (when none is available or the fitting stage fails) a grid fit of
the same structure.

* loop stage (OP -> PV): `diagnose.fit.fit_hammerstein` fitted on the training samples, or the
  Hammerstein fit of an identification (`diagnose.identify.Identification.fit`);
* valve stage (OP -> MV): the plain part (S, J, f0, start) of `diagnose.valve_fit.fit_valve`, or
  of an identification's valve fit.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import StictionError, StictionWarning
from .model import IDENTITY, Stage, Structure, predict
from .search import grid_baseline, refine_plain

#: ``Baseline.source`` values
SOURCES = ("fit_hammerstein", "fit_valve", "identify", "given", "grid")


@dataclass(frozen=True, eq=False)
class Baseline:
    """A stage's baseline model and its whole-record simulation.

    Attributes
    ----------
    structure : Structure
        Plain model (S = S_up = S_dn, no lag, drift, characteristic or load).
    y_hat : ndarray (n,)
        Whole-record simulation of the target, linear part fitted on the training samples.
    stem_hat : ndarray (n,)
        Simulated stem position.
    source : str
        One of `SOURCES`: the fitting stage on the training part (``fit_hammerstein``,
        ``fit_valve``), an identification passed in (``identify``: fitted on the whole record, its
        gain and offset refit on the training part), parameters passed in (``given``) or the grid.
    """

    structure: Structure
    y_hat: np.ndarray
    stem_hat: np.ndarray
    source: str


def _of(stage: Stage, struct: Structure, source: str) -> Baseline:
    y_hat, stem, _ = predict(stage, struct)
    return Baseline(struct, y_hat, stem, source)


def _start_state(fit) -> dict:
    """A fit's valve state at the first sample as `Structure` fields: stuck at ``start_stem_pct``
    (the input then at ``start_stuck_pct``), or at rest at ``start_op_pct`` instead of OP's first
    sample."""
    stem = getattr(fit, "start_stem_pct", None)
    if stem is not None:
        return {"y0_pct": float(stem), "xs0_pct": None if fit.start_stuck_pct is None
                else float(fit.start_stuck_pct)}
    at = getattr(fit, "start_op_pct", None)
    if at is not None:
        return {"y0_pct": float(at), "xs0_pct": float(at)}
    return {}


def from_hammerstein(fit) -> Structure:
    """The plain `Structure` of a `diagnose.fit.HammersteinFit`: its valve, process and the valve's
    state at the first sample (OP shifted by the fit's ``op_offset_pct`` is not supported: the
    stage shifts OP itself)."""
    return Structure.plain(float(fit.S_pct), float(fit.J_pct), int(fit.f0), fit.process).replace(**_start_state(fit))


def from_valve_fit(fit) -> Structure:
    """The plain `Structure` of a `diagnose.valve_fit.ValveFit` on the valve stage: (S, J, f0) and
    where the stem stood at the first sample; its own lag and dead time are left out (they are what
    the actuator_lag hypothesis tests)."""
    s = Structure.plain(float(fit.S_pct), float(fit.J_pct), int(getattr(fit, "f0", 1)), IDENTITY)
    if getattr(fit, "start_pct", None) is not None:
        s = s.replace(y0_pct=float(fit.start_pct))
    return s


def _from_fit_module(stage: Stage) -> Baseline | None:
    from ..fit import fit_hammerstein
    from ..valve_fit import fit_valve
    try:
        if stage.name == "loop":
            res = fit_hammerstein(stage.x, stage.y, stage.ts_s, train=stage.train,
                                  gain_sign=stage.gain_sign or None, surface=False)
            # simulated like every other model here (gain, offset and an integrating process's
            # balance refit on the training part), not with the fit's own slow load: that load is a
            # polynomial over the training part, and carried on into the held-out part it can miss
            # by many times PV's spread
            return _of(stage, from_hammerstein(res), "fit_hammerstein")
        # the plain valve: fit_valve's (S, J, f0); its own actuator lag and dead time, when it fits
        # them, are left out here (they are what the actuator_lag hypothesis tests)
        res = fit_valve(stage.x, stage.y, stage.ts_s, train=stage.train, surface=False)
        struct = Structure.plain(float(res.S_pct), float(res.J_pct), int(getattr(res, "f0", 1)), IDENTITY)
        return _of(stage, struct, "fit_valve")
    except StictionError as exc:
        warnings.warn(f"the fitting stage failed on the {stage.name} stage ({exc}); "
                      "using the grid baseline", StictionWarning, stacklevel=3)
    return None


def make_baseline(stage: Stage, given: Structure | None = None, *, source: str = "given",
                  use_fit_module: bool = True) -> Baseline:
    """The stage's baseline: ``given`` (``source`` says where it came from), from the fitting stage,
    or from the grid (refined locally)."""
    if given is not None:
        return _of(stage, given, source)
    if use_fit_module:
        b = _from_fit_module(stage)
        if b is not None:
            return b
    struct = grid_baseline(stage)
    struct, _ = refine_plain(stage, struct)
    return _of(stage, struct, "grid")
