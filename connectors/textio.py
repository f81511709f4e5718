"""Getting text out of a source: path or file object, BOM and encoding, binary files, separators.

Everything here raises `diagnose.errors.ConnectorError` with the file name in the message.
"""

from __future__ import annotations

import csv
import io
import os
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from diagnose.errors import ConnectorError

DELIMITERS = ("\t", ";", ",", "|")
_NAMES = {"\t": "tab", ";": "semicolon", ",": "comma", "|": "pipe"}
csv.field_size_limit(1 << 24)


@dataclass(frozen=True)
class Text:
    """Decoded text of a source and how it was decoded."""

    text: str
    label: str
    encoding: str
    bom: bool
    path: str | None


def load_text(source: Any) -> Text:
    """Read a path or file object (text or binary) into a string."""
    if hasattr(source, "read"):
        label = str(getattr(source, "name", "<stream>"))
        path = None
        try:
            raw = source.read()
        except (OSError, UnicodeDecodeError) as exc:
            raise ConnectorError(f"cannot read: {exc}", path=label) from None
    else:
        path = os.fspath(source)
        label = path
        if not os.path.exists(path):
            raise ConnectorError("file not found", path=label)
        if os.path.isdir(path):
            raise ConnectorError("is a folder, not a file", path=label)
        try:
            with open(path, "rb") as fh:
                raw = fh.read()
        except OSError as exc:
            raise ConnectorError(f"cannot read: {exc.strerror or exc}", path=label) from None
    if isinstance(raw, str):
        text, enc, bom = raw, "str", raw.startswith("\ufeff")
        if bom:
            text = text[1:]
    else:
        text, enc, bom = _decode(bytes(raw), label)
    if "\x00" in text[:65536] or _mostly_control(text[:65536]):
        raise ConnectorError("looks like a binary file, not a text export; export the data as CSV/text",
                             path=label)
    return Text(text, label, enc, bom, path)


def _decode(raw: bytes, label: str) -> tuple[str, str, bool]:
    head = raw[:8]
    if head.startswith(b"PK\x03\x04"):
        raise ConnectorError("is a zip/Excel (.xlsx) file, not a text export; save it as CSV", path=label)
    if head.startswith(b"\xd0\xcf\x11\xe0"):
        raise ConnectorError("is an old Excel (.xls) file, not a text export; save it as CSV", path=label)
    if head.startswith(b"\xef\xbb\xbf"):
        try:
            return raw[3:].decode("utf-8"), "utf-8", True
        except UnicodeDecodeError as exc:
            raise ConnectorError(f"has a UTF-8 BOM but invalid UTF-8 at byte {exc.start + 3}", path=label) from None
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16"), "utf-16", True
        except UnicodeDecodeError:
            raise ConnectorError("has a UTF-16 BOM but is not valid UTF-16", path=label) from None
    if b"\x00" in raw[:65536]:
        raise ConnectorError("looks like a binary file, not a text export; export the data as CSV/text",
                             path=label)
    for enc in ("utf-8", "cp1252"):
        try:
            return raw.decode(enc), enc, False
        except UnicodeDecodeError:
            continue
    return raw.decode("latin-1"), "latin-1", False


_CONTROL = re.compile("[\x00-\x08\x0e-\x1f\x7f-\x9f]")


def _mostly_control(text: str) -> bool:
    if not text:
        return False
    return len(_CONTROL.findall(text)) > 0.05 * len(text)


def sniff_delimiter(lines: list[str]) -> str:
    """The separator whose count is the same on most lines (header included)."""
    sample = [ln for ln in lines[:60] if ln.strip()]
    if not sample:
        return ","
    best, best_score = ",", -1.0
    for d in DELIMITERS:
        counts = [_count_outside_quotes(ln, d) for ln in sample]
        if max(counts) == 0:
            continue
        mode = max(set(counts), key=counts.count)
        if mode == 0:
            continue
        score = counts.count(mode) / len(counts) + 0.001 * mode
        if score > best_score + 1e-9:
            best, best_score = d, score
    return best


def _count_outside_quotes(line: str, d: str) -> int:
    if '"' not in line:
        return line.count(d)
    n, q = 0, False
    for c in line:
        if c == '"':
            q = not q
        elif c == d and not q:
            n += 1
    return n


def delimiter_name(d: str) -> str:
    return _NAMES.get(d, repr(d))


@dataclass
class Rows:
    """Parsed CSV rows with the 1-based file line where each row ends."""

    rows: list[list[str]]
    lines: list[int]


def split_rows(text: str, delimiter: str, label: str, *, start_line: int = 1) -> Rows:
    """CSV rows (blank rows dropped); an unterminated quote is an error naming the line."""
    rows: list[list[str]] = []
    lines: list[int] = []
    if '"' not in text:  # no quoting: a plain split is several times faster than the csv module
        for k, ln in enumerate(text.splitlines()):
            if ln.strip():
                rows.append(ln.split(delimiter))
                lines.append(k + start_line)
        if "\x0b" not in text and "\x0c" not in text and "\x1c" not in text and "\x1d" not in text \
                and "\x1e" not in text and "\x85" not in text and "\u2028" not in text and "\u2029" not in text:
            return Rows(rows, lines)
        rows, lines = [], []
    reader = csv.reader(io.StringIO(text), delimiter=delimiter, strict=True)
    try:
        for row in reader:
            if not row or (not row[0].strip() and not "".join(row).strip()):
                continue
            rows.append(row)
            lines.append(reader.line_num + start_line - 1)
    except csv.Error as exc:
        raise ConnectorError(f"malformed CSV ({exc}); an unterminated quote or a cut-off row?",
                             path=label, line=reader.line_num + start_line - 1) from None
    return Rows(rows, lines)


# ------------------------------------------------------------------------------------------ numbers

_DEC_COMMA = re.compile(r"^\s*[+-]?\d[\d.]*,\d+([eE][+-]?\d+)?\s*$")
_THOUSANDS = re.compile(r"^[+-]?\d{1,3}(,\d{3})+(\.\d+)?$")
_DEC_DOT = re.compile(r"^\s*[+-]?\d*\.\d+([eE][+-]?\d+)?\s*$")


def detect_decimal_comma(cells: list[str]) -> bool:
    """True when numbers are written with a decimal comma (``12,5``)."""
    comma = dot = 0
    for c in cells:
        if _DEC_COMMA.match(c):
            comma += 1
        elif _DEC_DOT.match(c):
            dot += 1
    return comma > dot


@dataclass
class Numbers:
    """A numeric column: values (NaN where bad/blank) and what was wrong.

    ``kind`` (only when something was wrong) marks each cell: 0 number, 1 blank, 2 text,
    3 NaN/inf.
    """

    values: np.ndarray
    n_blank: int
    n_text: int
    n_nonfinite: int
    examples: list[str]
    kind: np.ndarray | None = None


def to_numbers(cells: list[str], decimal_comma: bool = False) -> Numbers:
    """Convert cells to floats; text states, blanks, NaN and inf become NaN and are counted."""
    if decimal_comma:
        cells = [c.replace(".", "").replace(",", ".") if "," in c else c for c in cells]
    kind = None
    try:
        vals = np.array(cells, dtype=float)
        examples: list[str] = []
    except (ValueError, TypeError, OverflowError):
        vals = np.empty(len(cells))
        kind = np.zeros(len(cells), np.int8)
        seen: dict[str, int] = {}
        for k, c in enumerate(cells):
            try:
                vals[k] = float(c)
            except (ValueError, OverflowError):
                vals[k] = np.nan
                s = c.strip()
                if _THOUSANDS.match(s):  # 1,234.5
                    vals[k] = float(s.replace(",", ""))
                    continue
                if not s:
                    kind[k] = 1
                else:
                    kind[k] = 2
                    seen[s[:30]] = seen.get(s[:30], 0) + 1
        examples = [k for k, _ in sorted(seen.items(), key=lambda kv: -kv[1])[:4]]
    nonfinite = ~np.isfinite(vals)
    if np.any(nonfinite):
        if kind is None:
            kind = np.zeros(len(cells), np.int8)
        kind[nonfinite & (kind == 0)] = 3
        vals = np.where(nonfinite, np.nan, vals)
    if kind is None:
        return Numbers(vals, 0, 0, 0, examples)
    return Numbers(vals, int(np.count_nonzero(kind == 1)), int(np.count_nonzero(kind == 2)),
                   int(np.count_nonzero(kind == 3)), examples, kind)


# ------------------------------------------------------------------------------------------ quality

_GOOD_TEXT = {"good", "ok", "valid", "g", "normal", "true", "good [non-specific]"}


def quality_good(cells: list[str], column: str) -> tuple[np.ndarray, str]:
    """Which rows a quality column marks good, and the scheme used.

    Schemes: text (``Good``/``Bad``/``Questionable``/``Substituted``/``Uncertain``: only ``Good``
    passes), OPC (0-255, good when the two top bits are set: 192..255), IP.21 status (0 good, 1
    suspect, 2 bad), PHD confidence (0-100, good at 50 or above). The column name decides when the
    numbers fit several schemes (``status`` -> IP.21, ``conf`` -> PHD, ``quality`` -> OPC).
    """
    name = column.lower()
    numeric = True
    try:
        nums = np.array(cells, dtype=float)
    except (ValueError, TypeError, OverflowError):
        numeric = False
    if not numeric:
        good = np.array([c.strip().lower() in _GOOD_TEXT or c.strip().lower().startswith("good")
                         or not c.strip() for c in cells])
        return good, "text"
    fin = nums[np.isfinite(nums)]
    vals = set(np.unique(fin).tolist()) if fin.size else set()
    if "conf" in name:
        return nums >= 50, "phd_confidence"
    if "status" in name or (vals and vals <= {0.0, 1.0, 2.0} and "quality" not in name):
        return nums == 0, "ip21_status"
    if fin.size and fin.max() >= 64 and fin.max() <= 255 and np.all(fin == np.round(fin)):
        q = np.where(np.isfinite(nums), nums, 0).astype(np.int64)
        return (q & 0xC0) == 0xC0, "opc"
    if "quality" in name and vals <= {0.0, 192.0}:
        return nums == 192, "opc"
    return (nums >= 50) & (nums <= 100), "phd_confidence"
