"""Plain numbers for reports and command output: durations in s, min, h or days, values without
exponents. Every report, summary and command summary formats times and values through here, so
one loop's tau reads the same in its report, the plant summary and the terminal; and the units S
and J are given in (% of span, OP's own units, a fraction of span), so that every text sizes a
valve alike."""

from __future__ import annotations

import math
from typing import Any


def finite_or_none(value: Any) -> float | None:
    """``value`` as a float, or None where it is missing, not a number, a bool or not finite."""
    if value is None or isinstance(value, bool):
        return None
    try:
        f = float(value)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def duration(seconds: Any, none: str = "-") -> str:
    """A time span in the unit an engineer would say it in.

    Under 2 min in seconds (``"45 s"``, ``"2.5 s"``), under 2 h in minutes (``"58 min"``), under
    2 days in hours (``"23.9 h"``), beyond that in days (``"22.9 days"``). Three significant
    figures at most; never an exponent.
    """
    s = finite_or_none(seconds)
    if s is None:
        return none
    sign = "-" if s < 0 else ""
    a = abs(s)
    if a < 120:
        text = f"{_sig(a, 3)} s"
    elif a < 7200:
        text = f"{_sig(a / 60.0, 3)} min"
    elif a < 2 * 86400:
        text = f"{_sig(a / 3600.0, 3)} h"
    else:
        text = f"{_sig(a / 86400.0, 3)} days"
    return sign + text


def _sig(x: float, digits: int) -> str:
    """``x`` (>= 0) to ``digits`` significant figures in fixed notation, trailing zeros dropped;
    integers of more digits are written whole (``86604`` stays ``86604``, not ``8.66e+04``)."""
    if x == 0:
        return "0"
    mag = math.floor(math.log10(x))
    decimals = max(digits - 1 - mag, 0)
    text = f"{round(x, decimals):.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def number(value: Any, digits: int = 3, none: str = "-") -> str:
    """A value to ``digits`` significant figures in fixed notation (``0.0123``, ``0.0000312``,
    ``3480``, ``1979700``): never an exponent. Values under 1e-9 in size print as ``0``."""
    v = finite_or_none(value)
    if v is None:
        return none
    if abs(v) < 1e-9:
        return "0"
    return ("-" if v < 0 else "") + _sig(abs(v), digits)


def percent_change(fraction: Any, none: str = "-") -> str:
    """A relative change as a signed percentage: ``-0.05`` -> ``"-5 %"`` (a fall), ``0.05`` ->
    ``"+5 %"`` (a rise). The sign is the direction of the change, everywhere it is printed; a rise
    of more than ten times reads ``"> +999 %"``."""
    v = finite_or_none(fraction)
    if v is None:
        return none
    if v >= 9.995:
        # many times worse (against an exact reference, a noise-free stem): the digits say nothing
        return "> +999 %"
    r = int(round(100.0 * v))           # an int: no "-0 %" for a change that rounds to nothing
    return "0 %" if r == 0 else f"{r:+d} %"


def count(n: int, noun: str, plural: str | None = None) -> str:
    """``n`` and the noun in its number: ``count(1, "loop")`` -> ``"1 loop"``, ``count(0, "file")``
    -> ``"0 files"``."""
    return f"{n} {noun if n == 1 else (plural or noun + 's')}"


def percent(fraction: Any, none: str = "-") -> str:
    """A probability or share as a whole percentage (``0.97`` -> ``"97 %"``); above 99.5 % it reads
    ``"> 99 %"`` and below 0.5 % ``"< 1 %"``: a rounded 100 % would read as a certainty."""
    v = finite_or_none(fraction)
    if v is None:
        return none
    if v >= 0.995:
        return "> 99 %"
    if 0 < v < 0.005:
        return "< 1 %"
    return f"{100.0 * v:.0f} %"


# -- S and J's units: `Identification.op_units` ("% of span", "OP units", "fraction of span") --

def units_in_words(op_units: str) -> str:
    """S and J's units in words, for an `Identification.op_units` value (``"% of span"``, ``"OP
    units"``, ``"fraction of span"``): the one wording the verdict line, the reports, the command's
    output, the warnings and the evidence notes share."""
    return {"% of span": "% of valve span",
            "OP units": "in OP's own units, as OP is not in % of span",
            "fraction of span": "in fractions of span, as OP was logged"}.get(op_units, f"in {op_units}")


def pct_per_op_unit(op_units: str) -> float:
    """% of span per unit of OP (and so of S and J): 100 for OP logged as a fraction of span; 1 for
    OP in % and for OP in units whose span is unknown (there the % floors are taken as they are)."""
    return 100.0 if op_units == "fraction of span" else 1.0


def sj_decimals(op_units: str) -> int:
    """Decimals S and J are written with: two in % (and in OP's own units), four in fractions of
    span (the same resolution)."""
    return 4 if op_units == "fraction of span" else 2


def op_amount(value: float, op_units: str = "% of span") -> str:
    """An amount of OP travel (a valve band, a stuck stretch) in words, in OP's own units."""
    if op_units == "% of span":
        return f"{value:.2f} % of span"
    return f"{value:.3g} ({units_in_words(op_units)})"
