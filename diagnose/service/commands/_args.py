"""argparse types shared by the commands: a bad value is a usage error (exit 2) naming the flag,
checked while parsing, not a domain error from deep in the code that names a parameter instead."""

from __future__ import annotations

import argparse
import math
from typing import Callable


def whole_number(minimum: int, what: str) -> Callable[[str], int]:
    """A whole number of at least ``minimum``; ``what`` says what to give (``"1 or more"``)."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; give {what}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"{text}: give {what}")
        return v
    return parse


def number(low: float, *, above: bool = False, what: str) -> Callable[[str], float]:
    """A finite number of at least ``low`` (``above``: more than ``low``)."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; give {what}") from None
        if not math.isfinite(v) or v < low or (above and v == low):
            raise argparse.ArgumentTypeError(f"{text}: give {what}")
        return v
    return parse
