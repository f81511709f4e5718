"""Which column holds which role: the naming rule shared by every layout.

A column name is split at its last ``.``, ``:`` or ``/`` into a tag and a suffix (``FIC101.PV`` ->
tag ``FIC101``, suffix ``PV``); a name with no separator is its own suffix. Matching is
case-insensitive.

* OP (controller output): suffix ``OP``, ``OUT``, ``OUTPUT``, ``CO``, ``CV`` is *not* used (it means
  controlled variable in some plants); a **tag-style** ``.MV`` (``FIC101.MV``) is OP too, because
  DCSs such as Yokogawa CENTUM call the controller output the manipulated variable.
* MV (valve stem position): a **bare** ``MV`` column, or suffix ``POS``, ``POSITION``, ``STEM``,
  ``ZT``, ``VALVE_POSITION``, ``MV_PCT``.
* PV: suffix ``PV``, ``MEAS``, ``MEASUREMENT``. SP: suffix ``SP``, ``SV``, ``SETPOINT``.
* Mode: suffix ``MODE``, ``MD``, ``AM`` (controller mode: text ``AUTO``/``CAS``/``MAN``..., or a
  number where 0 = manual and any other value = automatic; the DCS export's ``.MODE`` 1 = auto).
* DeltaV parameter paths end in a field: ``FIC-101/PID1/PV.CV`` is tag ``FIC-101/PID1``, suffix
  ``PV`` (``.CV``, the current value, of any role's parameter; ``MODE.ACTUAL`` for the mode).
* A name with no ``.``, ``:`` or ``/`` may end in ``_`` and one of the abbreviations ``OP``, ``CO``,
  ``MV`` (OP, as ``.MV``), ``PV``, ``SP``, ``SV``, ``POS``, ``ZT``, ``MODE``, ``MD`` (or ``OP_PCT``,
  ``MV_PCT``): ``FIC_101_PV`` is tag ``FIC_101``, suffix ``PV``. Words (``_OUT``, ``_POSITION``)
  are not read this way: ``REACTOR_TEMP_OUT`` is no controller output.
* Units in brackets after a name are not part of it: ``FIC101.PV [m3/h]`` is ``FIC101.PV`` in m3/h.
* Time: ``time``, ``timestamp``, ``datetime``, ``date_time``, ``t``, ``ts``, ``_time``.

Anything else needs ``--op/--pv/--sp/--mv`` (or a tag map). Two columns claiming one role is an
error that names both.
"""

from __future__ import annotations

import re

OP_SUFFIXES = {"op", "out", "output", "co", "op_pct"}
MV_SUFFIXES = {"pos", "position", "stem", "zt", "valve_position", "mv_pct", "stem_position"}
PV_SUFFIXES = {"pv", "meas", "measurement"}
SP_SUFFIXES = {"sp", "sv", "setpoint", "set_point"}
MODE_SUFFIXES = {"mode", "md", "am", "ctrl_mode", "auto_manual"}
TIME_NAMES = {"time", "timestamp", "datetime", "date_time", "t", "ts", "_time", "time_s", "t_s"}

_ROLE_SUFFIXES = OP_SUFFIXES | MV_SUFFIXES | PV_SUFFIXES | SP_SUFFIXES | MODE_SUFFIXES | {"mv"}
_SPLIT = re.compile(r"^(.*)[.:/]([^.:/]+)$")
#: Suffixes read after an underscore (``FIC101_PV``), where names without a tag separator are
#: common (SCADA tag names): abbreviations only, since words such as ``_OUT`` or ``_POSITION``
#: also end names of other measurements (``REACTOR_TEMP_OUT``).
_UNDERSCORE_SUFFIXES = {"op", "co", "op_pct", "mv", "pv", "sp", "sv", "pos", "zt", "mv_pct", "mode", "md"}


#: DeltaV historian fields after a parameter path (``FIC-101/PID1/PV.CV``, ``.../MODE.ACTUAL``): the
#: role is the parameter before them.
_FIELDS = {"cv": None, "actual": "mode"}


_UNITS = re.compile(r"^(.*\S)\s+[\[(]([^\[\]()]*)[\])]$")


def strip_units(name: str) -> tuple[str, str | None]:
    """``"FIC101.PV [m3/h]"`` -> ``("FIC101.PV", "m3/h")``: units after the name, in brackets or
    parentheses, as spreadsheet and WinCC exports write them."""
    m = _UNITS.match(name)
    return (m.group(1), m.group(2).strip() or None) if m else (name, None)


def split_tag(name: str) -> tuple[str, str]:
    """``"FIC101.PV"`` -> ``("FIC101", "pv")``; ``"PV"`` -> ``("", "pv")``;
    ``"FIC-101/PID1/OUT.CV"`` -> ``("FIC-101/PID1", "out")``."""
    name = name.strip().strip('"').strip()
    name = strip_units(name)[0]
    m = _SPLIT.match(name)
    if m and m.group(2).lower() in _FIELDS:
        param = split_tag(m.group(1))
        if param[1] in _ROLE_SUFFIXES and _FIELDS[m.group(2).lower()] in (None, param[1]):
            return param
    if m:
        return m.group(1), m.group(2).lower()
    low = name.lower()
    if low not in _ROLE_SUFFIXES and low not in TIME_NAMES:
        # the first underscore that leaves a tag before a role abbreviation: FIC_101_PV, TI101_SP
        for i in (k for k, ch in enumerate(name) if ch == "_" and k > 0):
            if low[i + 1:] in _UNDERSCORE_SUFFIXES:
                return name[:i], low[i + 1:]
    return "", low


def role_of(name: str) -> str | None:
    """The role a column name implies (``op``, ``pv``, ``sp``, ``mv``, ``mode``, ``time``) or None."""
    tag, suffix = split_tag(name)
    if not tag and suffix in TIME_NAMES:
        return "time"
    if suffix == "mv":
        return "op" if tag else "mv"
    if suffix in OP_SUFFIXES:
        return "op"
    if suffix in MV_SUFFIXES:
        return "mv"
    if suffix in PV_SUFFIXES:
        return "pv"
    if suffix in SP_SUFFIXES:
        return "sp"
    if suffix in MODE_SUFFIXES:
        return "mode"
    return None


#: The label the DataFrame reader gives its source (`connectors.frame`). A frame is read from
#: Python, where the reading options are keywords (``ts_s=``) and a tag map does not apply, so
#: the hints of its messages name the keyword rather than the command-line flag (``--ts-s``).
FRAME_LABEL = "<DataFrame>"


def option(flag: str, label: str | None, value: str = "") -> str:
    """The reading option ``flag`` (``"--ts-s"``), with an optional ``value``, as the user who read
    ``label`` gives it: ``--ts-s SECONDS`` for a file, ``ts_s=SECONDS`` for a DataFrame."""
    if label == FRAME_LABEL:
        return flag.lstrip("-").replace("-", "_") + "=" + value
    return f"{flag} {value}" if value else flag
