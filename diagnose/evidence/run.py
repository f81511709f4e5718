"""Run every evidence test on one record."""

from __future__ import annotations

from ._signals import Prepared, pv_usable
from .area_peak import _singhal_area
from .bicoherence import _choudhury_bicoherence
from .curve_fit import _he_curve_fit
from .d2pdf import _horch_integrating
from .op_shape import _op_shape
from .qsa import _yamashita_qsa
from .result import Evidence, cannot_judge
from .stuck import _kano_stuck
from .xcorr import _horch_xcorr

# name -> runner on a prepared record; the order is the order of run_all's result
_TESTS = {
    "horch_xcorr": lambda p, i: _horch_xcorr(p, i),
    "horch_integrating": lambda p, i: _horch_integrating(p, i),
    "he_curve_fit": lambda p, i: _he_curve_fit(p, i),
    "choudhury_bicoherence": lambda p, i: _choudhury_bicoherence(p),
    "kano_stuck": lambda p, i: _kano_stuck(p, i),
    "yamashita_qsa": lambda p, i: _yamashita_qsa(p, i),
    "singhal_area": lambda p, i: _singhal_area(p, i),
    "op_shape": lambda p, i: _op_shape(p),
}
TESTS = tuple(_TESTS)


def run_all(op, pv, ts_s: float, *, sp=None, integrating: bool | None = None,
            op_units: str = "% of span") -> tuple[Evidence, ...]:
    """Every evidence test on one record, in the order of `TESTS`; never raises.

    Parameters
    ----------
    op : array (n,)
        Controller output, % of span.
    pv : array (n,) or None
        Process variable (None, or an unusable PV, leaves only the OP-only test judging).
    ts_s : float
        Sample period, seconds.
    sp : array (n,), optional
        Setpoint; where it moves, the tests that read the control error use SP - PV.
    integrating : bool or None
        True for a level or other integrating loop, False for a self-regulating one. The caller
        knows it (the fitted process model, the tag type); with None the tests that need it say
        they cannot judge, and the others run.
    op_units : str
        OP's units, where OP is not in % of span (``"OP units"``, ``"fraction of span"``): the
        notes that give an amount of OP travel say it in these units.

    Returns
    -------
    tuple of Evidence
        One per test; a test that cannot run on the record says ``cannot_judge`` and why.
    """
    try:
        p = Prepared(op, pv, ts_s, sp, op_units=op_units)
    except Exception as exc:  # noqa: BLE001 - a record no test can read is a cannot-judge, not a crash
        return tuple(cannot_judge(t, "bad_input", f"The record could not be read ({type(exc).__name__}: {exc}).")
                     for t in TESTS)
    integ = None if integrating is None else bool(integrating)
    out = []
    for name, run in _TESTS.items():
        try:
            out.append(run(p, integ))
        except Exception as exc:  # noqa: BLE001 - one failing test must not take the others down
            out.append(cannot_judge(name, "internal_error", f"The test failed on this record "
                                    f"({type(exc).__name__}: {exc}); please report it."))
    return tuple(out)


__all__ = ["run_all", "pv_usable", "TESTS"]
