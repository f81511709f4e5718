"""Missing-physics hypotheses, one module each, and their registry.

`REGISTRY` maps each name to an instance, built from the explicit imports below (no discovery);
`register` adds another (a subclass of `PhysicsHypothesis`), `get` looks them up by name.

* `actuator_lag.ActuatorLag`: a first-order lag of the stem after the friction element;
* `asymmetric_stiction.AsymmetricStiction`: separate (S, J) opening and closing;
* `valve_characteristic.ValveCharacteristic`: an installed characteristic (operating-point gain);
* `external_disturbance.ExternalDisturbance`: an oscillating load not caused by the valve;
* `time_varying_friction.TimeVaryingFriction`: S and J drifting over the record.
"""

from __future__ import annotations

from typing import Iterable, Mapping

from ...errors import DataError
from .actuator_lag import ActuatorLag
from .asymmetric_stiction import AsymmetricStiction
from .base import (MIN_LOAD_SHARE, MIN_RELATIVE_EFFECT, PROCESS_SIDE, VALVE_SIDE, Fitted, PhysicsHypothesis,
                   PlainModel)
from .external_disturbance import ExternalDisturbance
from .time_varying_friction import TimeVaryingFriction
from .valve_characteristic import ValveCharacteristic

__all__ = ["REGISTRY", "register", "get", "shown_params", "PhysicsHypothesis", "PlainModel", "Fitted",
           "VALVE_SIDE", "PROCESS_SIDE", "MIN_RELATIVE_EFFECT", "MIN_LOAD_SHARE", "ActuatorLag", "AsymmetricStiction",
           "ValveCharacteristic", "ExternalDisturbance", "TimeVaryingFriction"]

REGISTRY: dict[str, PhysicsHypothesis] = {}


def register(hypothesis: PhysicsHypothesis) -> PhysicsHypothesis:
    """Add a hypothesis to the registry (its `name` must be new)."""
    if not isinstance(hypothesis, PhysicsHypothesis):
        raise TypeError(f"{hypothesis!r} is not a PhysicsHypothesis")
    if not hypothesis.name or hypothesis.name in REGISTRY:
        raise ValueError(f"hypothesis name {hypothesis.name!r} is empty or already registered")
    REGISTRY[hypothesis.name] = hypothesis
    return hypothesis


for _h in (ActuatorLag(), AsymmetricStiction(), ValveCharacteristic(), ExternalDisturbance(), TimeVaryingFriction()):
    register(_h)


def shown_params(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """The fitted parameters of hypothesis ``name`` a reader needs (`PhysicsHypothesis.shown`; all
    of them for a name not registered here)."""
    return REGISTRY[name].shown(params) if name in REGISTRY else dict(params)


def get(names: Iterable[str] | None = None) -> list[PhysicsHypothesis]:
    """Registered hypotheses by name (all, in registry order, when ``names`` is None)."""
    if names is None:
        return list(REGISTRY.values())
    out = []
    for nm in names:
        if nm not in REGISTRY:
            raise DataError(f"unknown hypothesis {nm!r}; choose from {', '.join(REGISTRY)}")
        out.append(REGISTRY[nm])
    return out
