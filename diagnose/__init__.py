"""Control-valve stiction diagnostics.

The front door (docs/api.md)::

    import diagnose

    result = diagnose.identify("FIC101.csv")           # or a DataFrame, or a LoopRecord
    result.S_pct, result.J_pct, result.cls, result.stiction_probability
    result.to_dict()                                   # what `stiction identify --json` prints
    result.plot()                                      # the report's trends figure
    records = diagnose.read_loops("unit7.csv")         # every loop of a file, folder or DataFrame
    why = diagnose.explain("FIC101.csv")               # the missing physics (3-40 s)

Names are imported on first use, so ``import diagnose`` costs almost nothing and a command that
needs none of them does not pay for them.
"""

from __future__ import annotations

import importlib

TYPE_CHECKING = False  # typing.TYPE_CHECKING without importing typing: `import diagnose` stays cheap

# name -> module that defines it
_EXPORTS = {
    "identify": "diagnose.api",
    "explain": "diagnose.api",
    "read_loops": "diagnose.api",
    "Identification": "diagnose.identification",
    "Detection": "diagnose.identification",
    "ClassTest": "diagnose.identification",
    "Note": "diagnose.notes",
    "LoopRecord": "diagnose.record",
    "Finding": "diagnose.record",
    "valve_activity": "diagnose.activity",
    "ValveActivity": "diagnose.activity",
    "Evidence": "diagnose.evidence",
    "Verdict": "diagnose.verdict",
    "ProcessModel": "diagnose.process_model",
    "Selection": "diagnose.narx.bank",
    "Diagnosis": "diagnose.service.pipeline",
    "StictionEstimator": "diagnose.fit",
    "StictionError": "diagnose.errors",
    "DataError": "diagnose.errors",
}

__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:  # for type checkers and editors; at run time names load on first use
    from .activity import ValveActivity, valve_activity
    from .api import explain, identify, read_loops
    from .errors import DataError, StictionError
    from .evidence import Evidence
    from .fit import StictionEstimator
    from .identification import ClassTest, Detection, Identification
    from .narx.bank import Selection
    from .notes import Note
    from .process_model import ProcessModel
    from .record import Finding, LoopRecord
    from .service.pipeline import Diagnosis
    from .verdict import Verdict


def __getattr__(name: str) -> object:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'diagnose' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
