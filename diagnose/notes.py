"""`Note`: one warning or remark attached to a result (identification, diagnosis, explanation)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator


@dataclass(frozen=True)
class Note:
    """A warning on a result, for a control engineer.

    Attributes
    ----------
    code : str
        Stable machine-readable name (``"poor_fit"``, ``"data_quality.gap"``,
        ``"robustness.outside_region"``, ``"service.narx_unavailable"``...); docs/api.md lists them.
    message : str
        One or two sentences: what limits the result and what to do about it.
    """

    code: str
    message: str

    def to_dict(self) -> dict[str, str]:
        """``{"code": ..., "message": ...}``: the JSON form in every result."""
        return {"code": self.code, "message": self.message}

    def __iter__(self) -> Iterator[tuple[str, str]]:
        """``(key, value)`` pairs, so that ``dict(note)`` is the JSON form too."""
        return iter(self.to_dict().items())

    def __str__(self) -> str:
        return f"[{self.code}] {self.message}"
