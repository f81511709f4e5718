"""Connectors: historian exports and Modbus/TCP devices into `diagnose.record.LoopRecord`s."""

from __future__ import annotations

import os
from typing import IO, Any

from diagnose.record import LoopRecord


def read_records(source: str | os.PathLike | IO[str], **options: Any) -> list[LoopRecord]:
    """Read every loop in a historian export (one file or file object) into records.

    ``options`` are the column overrides (``op``, ``pv``, ``sp``, ``mv``, ``ts``), ``ts_s`` and
    ``name``. Raises `diagnose.errors.ConnectorError` with a one-line message on bad input.
    """
    from .historian import read_wide

    return [read_wide(source, **options)]
