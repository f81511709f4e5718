"""The contract every missing-physics hypothesis keeps.

A hypothesis is an augmented model with a few physical parameters. `PhysicsHypothesis.fit(stage,
baseline)` fits it on the training samples of one `Stage`, starting from `PlainModel`: the plain
model it augments (the *reference*, refit on this stage by the shared searches of
`diagnose.physics.search`, so that a gain is due to the added physics and not to a different
search) and what the localisation found about its misfit. It returns a `Fitted`.

The base class does what every hypothesis shares (validation, the valve's initial state, never
returning a worse fit than the plain model it nests, the parameters it reports) and leaves two
steps to each subclass: `_search` (the hypothesis's own search) and `_params` (its physical
parameters from the fitted structure), as pysindy's feature libraries leave one step each.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar, Mapping

import numpy as np

from ...errors import DataError
from ..model import Stage, Structure, predict
from ..search import best_of, fit_initial_state, refine_sj, refit_dynamics

#: smallest change a valve-side hypothesis must make to S or J, relative to S, to be named: a few
#: per cent is within the resolution of the plain model's own S (a slightly wrong plain S drifts
#: out of step late in the record, and a tiny drift or asymmetry can put it back)
MIN_RELATIVE_EFFECT = 0.10
#: smallest share of the plain model's training residual power an external load must carry to be named
MIN_LOAD_SHARE = 0.10

VALVE_SIDE = "valve"
PROCESS_SIDE = "process"
#: fewest training samples a hypothesis is fitted on
MIN_TRAIN_SAMPLES = 50


@dataclass(frozen=True, eq=False)
class PlainModel:
    """The plain model a hypothesis augments, and what the localisation found about its misfit.

    Parameters
    ----------
    structure : Structure
        The reference: the plain model (S = S_up = S_dn, no lag, drift, characteristic or load)
        refit on this stage's training part; every search starts from it.
    identified : Structure, optional
        The fitting stage's plain model (the baseline), a second start: a drifting valve's plain
        fit, for one, sits near its mid-span S.
    limit_cycle_period_s : float, optional
        Period of the loop's own oscillation (a load at one of its harmonics is not searched).
    residual : ndarray (n,), optional
        Target minus the reference's whole-record simulation (its spectral peaks are load periods
        worth trying); computed from ``structure`` when not given.
    """

    structure: Structure
    identified: Structure | None = None
    limit_cycle_period_s: float | None = None
    residual: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Fitted:
    """A fitted hypothesis on one stage.

    Parameters
    ----------
    name : str
        Hypothesis name.
    params : mapping str -> float
        Its physical parameters, units in the names (read-only).
    structure : Structure
        The whole augmented model (for simulation).
    n_extra : int
        Parameters added to the plain model (for the information criterion).
    train_sse : float
        Training sum of squared errors.
    stage : str
        ``loop`` (OP -> PV) or ``valve`` (OP -> MV).
    """

    name: str
    params: Mapping[str, float]
    structure: Structure
    n_extra: int
    train_sse: float
    stage: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))


class PhysicsHypothesis:
    """Base class of a missing-physics hypothesis.

    Subclasses set the class attributes and implement `_search(stage, baseline) -> Structure` and
    `_params(structure, reference, stage, coef) -> dict`; `material` may refuse effects too small to
    be physics.

    Attributes
    ----------
    name : str
        Registry name (also the JSON's ``missing_physics``).
    param_names : tuple of str
        Keys of `Fitted.params`, units in the names.
    side : {"valve", "process"}
        Valve-side effects are judged on the valve stage (OP -> MV) when the stem position is
        recorded, process-side ones on the loop stage (OP -> PV).
    n_extra : int
        Parameters added to the plain model (the information criterion's penalty).
    description : str
        A few words for the explanation's text.
    """

    name: ClassVar[str] = ""
    param_names: ClassVar[tuple[str, ...]] = ()
    side: ClassVar[str] = VALVE_SIDE
    n_extra: ClassVar[int] = 1
    description: ClassVar[str] = ""

    def applicable(self, stage: Stage) -> bool:
        """Whether the hypothesis can be tested on this stage."""
        if self.side == PROCESS_SIDE:
            return stage.name == "loop"
        return stage.name in ("loop", "valve")

    def fit(self, stage: Stage, baseline: PlainModel) -> Fitted:
        """Fit the augmented model on the stage's training samples, starting from ``baseline``.

        Never trains worse than ``baseline.structure``, the plain model it nests.
        """
        if not self.applicable(stage):
            raise DataError(f"hypothesis {self.name!r} cannot be tested on the {stage.name} stage")
        if int(stage.train.sum()) < MIN_TRAIN_SAMPLES:
            raise DataError(f"hypothesis {self.name!r} needs at least {MIN_TRAIN_SAMPLES} training samples")
        return self._finish(stage, self._search(stage, baseline), baseline.structure)

    def refit(self, stage: Stage, fitted: Fitted, baseline: PlainModel) -> Fitted:
        """Polish ``fitted`` again after the plain model improved to ``baseline`` (a projection of
        some fitted hypothesis onto the plain model trained better than the reference ``fitted``
        started from): from ``fitted`` itself and from its extra physics carried over to the new
        plain model (`transplants`), with the hypothesis's local polish (`_polish`) only. The
        global searches of `fit` are not repeated: what they found is in ``fitted``."""
        if not self.applicable(stage):
            raise DataError(f"hypothesis {self.name!r} cannot be tested on the {stage.name} stage")
        start, _ = best_of(stage, [fitted.structure] + transplants(stage, fitted.structure, baseline.structure))
        return self._finish(stage, self._polish(stage, start, again=True), baseline.structure)

    def _polish(self, stage: Stage, struct: Structure, again: bool = False) -> Structure:
        """The local end of the hypothesis's search (default: S and J on a local grid, then the
        process dynamics). ``again``: polishing a fitted model again (`refit`), whose own search
        profiled what is slow to profile."""
        struct, _ = refine_sj(stage, struct, s_span=0.04, n_s=9, j_span=0.15, n_j=5)
        struct, _ = refit_dynamics(stage, struct, rounds=1)
        return struct

    def _finish(self, stage: Stage, struct: Structure, reference: Structure) -> Fitted:
        if struct.y0_pct is not None:
            # the valve's initial state moves a little with the added physics
            struct, _ = fit_initial_state(stage, struct, local=True)
        # the augmented model nests the plain one: never return a worse fit than the reference
        struct, sse = best_of(stage, [struct, reference])
        _, _, coef = predict(stage, struct)
        params = {k: float(v) for k, v in self._params(struct, reference, stage, coef).items()}
        missing = set(self.param_names) - set(params)
        if missing:  # pragma: no cover - programming error in a subclass
            raise RuntimeError(f"{self.name}: params lack {sorted(missing)}")
        return Fitted(name=self.name, params=params, structure=struct, n_extra=self.n_params(struct),
                      train_sse=sse, stage=stage.name)

    def _search(self, stage: Stage, baseline: PlainModel) -> Structure:
        raise NotImplementedError

    def n_params(self, struct: Structure) -> int:
        """Parameters the fitted ``struct`` adds to the plain model (default `n_extra`; a
        hypothesis with variants of different size says which its fit is)."""
        return self.n_extra

    def material(self, params: Mapping[str, float], record_s: float, residual_rms: float) -> bool:
        """Whether the fitted effect is large enough to be physics rather than a nudge within the
        plain model's own resolution (default: always). ``record_s``: record length, seconds;
        ``residual_rms``: the plain model's training residual, RMS in target units."""
        return True

    def shown(self, params: Mapping[str, float]) -> dict[str, float]:
        """The fitted parameters a reader needs, for the explanation's text and the reports (the
        JSON output keeps them all); default: all of them."""
        return dict(params)

    def _params(self, struct: Structure, reference: Structure, stage: Stage, coef) -> dict:
        raise NotImplementedError


def transplants(stage: Stage, fitted: Structure, plain: Structure) -> list[Structure]:
    """A fitted augmented model carried over to another plain model: the augmented valve with the
    plain model's process and start state (on the valve stage the process, i.e. the dead time, is
    the augmented model's own), and the plain model with the fitted extra physics (a lag, a
    characteristic, a load, a drift relative to S, an asymmetry relative to S)."""
    process = fitted.process if stage.fixed_dynamics else plain.process
    out = [fitted.replace(process=process, y0_pct=plain.y0_pct, xs0_pct=plain.xs0_pct, f0=plain.f0)]
    s_mean = 0.5 * (fitted.S_up_pct + fitted.S_dn_pct)
    k = plain.S_up_pct / s_mean if s_mean > 0 else 1.0
    out.append(plain.replace(S_up_pct=fitted.S_up_pct * k, S_dn_pct=fitted.S_dn_pct * k,
                             J_up_pct=fitted.J_up_pct * k, J_dn_pct=fitted.J_dn_pct * k,
                             dS_pct_per_s=fitted.dS_pct_per_s * k, dJ_pct_per_s=fitted.dJ_pct_per_s * k,
                             drift_from_s=fitted.drift_from_s, drift_for_s=fitted.drift_for_s,
                             tau_lag_s=fitted.tau_lag_s, char_c=fitted.char_c, period_s=fitted.period_s,
                             process=process))
    return out
