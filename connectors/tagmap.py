"""Tag maps: which historian tags make which loop, in which role, in which range.

A TOML file (read with the standard library's ``tomllib``)::

    # optional reading options for every file read with this map
    tz = "Europe/Berlin"        # naive local times in the export
    dst = "infer"               # infer | earliest | latest | raise
    dayfirst = true             # 05/03/2026 is 5 March (false: 3 May); default: the dates decide

    [loops.FIC211]
    op = { tag = "FV_211", range = [0, 100] }    # range: engineering values of 0 % and 100 % of span
    pv = { tag = "FT_211", units = "m3/h" }
    sp = "FIC211.SP"                              # a bare string is just the tag
    mode = { tag = "FIC211.MODE", auto = [1] }    # values meaning automatic (default: any non-zero)

    [loops.LIC106]
    op = { tag = "LV_106", range = [4, 20], units = "mA" }
    pv = "LT_106"

Roles are ``op``, ``pv``, ``sp``, ``mv`` (stem position) and ``mode``. OP and MV with a ``range``
are scaled to % of span: ``100 * (x - lo) / (hi - lo)`` (``lo > hi`` for reverse-acting signals).
One map may hold any number of loops; a loop whose OP or PV tag is not in a file is skipped for
that file. Tags match case-insensitively.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from typing import Any, Mapping

from diagnose.errors import ConnectorError

ROLES = ("op", "pv", "sp", "mv", "mode")
OPTION_KEYS = {"tz", "dst", "dayfirst", "fmt", "format", "ts_s", "max_gap_s", "min_samples"}


@dataclass(frozen=True)
class RoleMap:
    tag: str
    range: tuple[float, float] | None = None
    units: str | None = None
    auto: tuple[float, ...] | None = None


@dataclass(frozen=True)
class LoopMap:
    name: str
    roles: Mapping[str, RoleMap]


@dataclass(frozen=True)
class TagMap:
    loops: Mapping[str, LoopMap]
    options: Mapping[str, Any] = field(default_factory=dict)
    path: str | None = None


def _role(value: Any, where: str, path: str) -> RoleMap:
    if isinstance(value, str):
        return RoleMap(value.strip())
    if not isinstance(value, dict) or "tag" not in value:
        raise ConnectorError(f"{where} must be a tag name or a table with 'tag'", path=path)
    rng = value.get("range")
    if rng is not None:
        if (not isinstance(rng, list) or len(rng) != 2
                or not all(isinstance(v, (int, float)) for v in rng) or rng[0] == rng[1]):
            raise ConnectorError(f"{where}.range must be two different numbers [lo, hi]", path=path)
        rng = (float(rng[0]), float(rng[1]))
    auto = value.get("auto")
    if auto is not None:
        if not isinstance(auto, list) or not all(isinstance(v, (int, float)) for v in auto):
            raise ConnectorError(f"{where}.auto must be a list of numbers", path=path)
        auto = tuple(float(v) for v in auto)
    unknown = set(value) - {"tag", "range", "units", "auto"}
    if unknown:
        raise ConnectorError(f"{where} has unknown keys {sorted(unknown)} (allowed: tag, range, units, auto)",
                             path=path)
    return RoleMap(str(value["tag"]).strip(), rng, value.get("units"), auto)


def parse_tagmap(data: Mapping[str, Any], path: str = "<tag map>") -> TagMap:
    """A `TagMap` from already-parsed TOML data."""
    loops_raw = data.get("loops")
    if not isinstance(loops_raw, dict) or not loops_raw:
        raise ConnectorError("tag map has no [loops.<NAME>] tables", path=path)
    loops: dict[str, LoopMap] = {}
    for name, spec in loops_raw.items():
        if not isinstance(spec, dict):
            raise ConnectorError(f"loops.{name} must be a table", path=path)
        unknown = set(spec) - set(ROLES)
        if unknown:
            raise ConnectorError(f"loops.{name} has unknown roles {sorted(unknown)} (allowed: {', '.join(ROLES)})",
                                 path=path)
        for need in ("op", "pv"):
            if need not in spec:
                raise ConnectorError(f"loops.{name} needs an {need} tag", path=path)
        loops[str(name)] = LoopMap(str(name), {r: _role(v, f"loops.{name}.{r}", path) for r, v in spec.items()})
    options = {k: v for k, v in data.items() if k in OPTION_KEYS}
    # the date order is the plant's (its historian's locale), not a loop's: one key for the map
    if "dayfirst" in options and not isinstance(options["dayfirst"], bool):
        raise ConnectorError(f"dayfirst must be true (day first: 05/03/2026 is 5 March) or false (month "
                             f"first), not {options['dayfirst']!r}", path=path)
    unknown = set(data) - OPTION_KEYS - {"loops"}
    if unknown:
        raise ConnectorError(f"tag map has unknown top-level keys {sorted(unknown)}", path=path)
    return TagMap(loops, options, path)


def load_toml(path: str | os.PathLike, what: str) -> dict[str, Any]:
    """Read a TOML file; errors name the file, ``what`` it is and, for TOML syntax, the line."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise ConnectorError(f"{what} file not found", path=path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConnectorError(f"{what} is not valid TOML: {exc}", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConnectorError(f"cannot read {what}: {exc}", path=path) from None


def load_tagmap(path: str | os.PathLike) -> TagMap:
    """Read a tag map TOML file (errors name the file and, for TOML syntax, the line)."""
    path = os.fspath(path)
    data = load_toml(path, "tag map")
    return parse_tagmap(data, path)
