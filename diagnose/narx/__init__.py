"""NARX networks for the valve (OP -> stem position), the NARX-SP model bank and the seed paper's
experiments (docs/narx.md, docs/reproduction.md).

Importing this package is cheap: torch is imported only by `diagnose.narx.networks` and by the bank
functions that run or train a network.

Modules: ``protocol`` (fixed data protocol), ``metrics`` (RMSE, CDC), ``networks`` (the six network
types behind one interface), ``kernels`` (compiled free-run loops), ``experiments`` (Tables I-III,
model mode), ``bank`` (model bank, selection, robustness maps).
"""

from __future__ import annotations

__all__ = ["load_bank", "Bank", "Selection"]


def __getattr__(name):
    if name in __all__:
        from . import bank
        return getattr(bank, name)
    raise AttributeError(name)
