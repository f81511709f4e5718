"""Exception and warning types shared by every part of the tool.

One root (`StictionError`); each subclass also inherits the built-in it resembles so that callers
who catch ``ValueError`` or ``OSError`` keep working. Messages say what was found and what to do.
"""

from __future__ import annotations


class StictionError(Exception):
    """Root of every error this package raises on purpose."""


class DataError(StictionError, ValueError):
    """The data cannot be used as given (too short, constant, missing a role, non-finite...)."""


class ConnectorError(StictionError, OSError):
    """A source (file, historian export, device) could not be read.

    Parameters
    ----------
    message : str
        What is wrong and what to do about it.
    path : str, optional
        The file or address involved; prefixed to the message.
    line : int, optional
        1-based line number in the file, when one is to blame.
    column : str, optional
        Column name, when one is to blame.
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None,
                 column: str | None = None) -> None:
        self.message = message
        self.path = path
        self.line = line
        self.column = column
        where = ""
        if path is not None:
            where = str(path)
            if line is not None:
                where += f":{line}"
            if column is not None:
                where += f" (column {column!r})"
            where += ": "
        elif column is not None:
            where = f"column {column!r}: "
        super().__init__(where + message)


class ShortRecordError(ConnectorError, DataError):
    """A source was read, but holds too few samples to diagnose: a `ConnectorError` as the reader
    raises it, and a `DataError` as unusable data (too short) is documented to be."""


class ModbusReadError(ConnectorError):
    """A Modbus device answered with an error or did not answer."""


class NotFittedError(StictionError, AttributeError):
    """An estimator was used before `fit`."""


class StictionWarning(UserWarning):
    """Numerical or data trouble that does not stop the computation."""
