"""Checks every measured CSV reader shares: the file is UTF-8 text with commas, its numbers are
numbers, and its time strictly increases.

:func:`check_text_file` and :func:`delimiter_hint` name a UTF-16 or a semicolon- or tab-delimited
file and say how to save it. :func:`is_number` is the grammar of a number in a CSV (Python's
``float`` also takes ``0.21_5`` and non-ASCII digits, which numpy's parser refuses).
:func:`check_time_order` counts repeated and decreasing stamps and names the first rows.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from pe_drake.exceptions import DataError, shorten

#: A step shorter than this fraction of the mean step repeats the previous stamp (1 µs at 1 kHz).
NEAR_DUPLICATE = 1e-3
#: Row numbers listed in a message.
ROWS_SHOWN = 5

_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|[+-]?(nan|inf|infinity)", re.ASCII | re.IGNORECASE)
_BOMS = {b"\xff\xfe": "UTF-16 (little-endian byte-order mark FF FE)", b"\xfe\xff": "UTF-16 (big-endian byte-order mark FE FF)"}
SAVE_AS_UTF8 = "save it as comma-separated UTF-8 (CSV UTF-8 in Excel)"


def is_number(text: str) -> bool:
    """Whether a CSV field is a number: ASCII digits, one point, an exponent, nan or inf."""
    return _NUMBER.fullmatch(text.strip()) is not None


def check_text_file(path: str | Path) -> None:
    """Refuses a file that is not UTF-8 text (a UTF-16 byte-order mark, NUL bytes, or bytes that
    do not decode as UTF-8 in its first 64 kB), saying what it looks like and how to save it."""
    with open(path, "rb") as f:
        head = f.read(65536)
    looks = next((what for bom, what in _BOMS.items() if head.startswith(bom)), None)
    if looks is None and b"\x00" in head:
        looks = "UTF-16 or binary (it has NUL bytes)"
    if looks is not None:
        raise DataError(f"the file looks {looks}, not UTF-8 text: {SAVE_AS_UTF8}", file=str(path))
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as err:
        if len(head) < 65536 or err.start < len(head) - 4:  # not a character cut at the 64 kB boundary
            line = head.count(b"\n", 0, err.start) + 1
            raise DataError(f"line {line}: byte {head[err.start]:#04x} is not UTF-8 text (Latin-1 or another "
                            f"encoding?): {SAVE_AS_UTF8}", file=str(path)) from None


def delimiter_hint(header: str, file: str) -> None:
    """Refuses a header that is one column of a semicolon- or tab-delimited file."""
    if "," in header:
        return
    for mark, name in ((";", "semicolon"), ("\t", "tab")):
        if mark in header:
            raise DataError(f"the header has no commas but {header.count(mark)} {name}s: the file looks {name}-delimited; "
                            f"{SAVE_AS_UTF8} with decimal points, or name its columns in data.columns (that reader "
                            "takes ; and tabs)", file=file)


def first_non_number(rows, columns: dict[int, str]) -> tuple[int, int, str, str] | None:
    """(data row from 1, file line, column name, the field cut for a message) of the first field
    that is not a number, or None; ``rows``: (file line, fields) of each data row, ``columns``:
    {field index: column name} to check."""
    for r, (line, fields) in enumerate(rows):
        for k, name in columns.items():
            raw = fields[k].strip() if k < len(fields) else ""
            if not is_number(raw):
                return r + 1, line, name, shorten(raw)
    return None


def _rows_text(indices: np.ndarray, lines) -> str:
    rows = ", ".join(str(int(k) + 1) for k in indices[:ROWS_SHOWN]) + (", …" if len(indices) > ROWS_SHOWN else "")
    if lines is None:
        return f"row(s) {rows}"
    shown = ", ".join(str(lines[int(k)]) for k in indices[:ROWS_SHOWN])
    return f"row(s) {rows} (line(s) {shown} of the file)"


def check_time_order(t: np.ndarray, file: str = "", lines=None, column: str = "t") -> None:
    """Refuses repeated and decreasing time stamps, with their counts and first rows.

    A stamp within :data:`NEAR_DUPLICATE` × the mean step of the previous one counts as a
    repeat: interpolating across it divides by ~0, and it shrinks the median step so that
    every real step looks like a hole.

    ``t``: the time column, (T,) [s]; ``lines``: the file line of each sample, when known.

    Raises:
        DataError: naming the file, the column and the first bad row (data rows from 1).
    """
    t = np.asarray(t, float)
    if len(t) < 2:
        return
    steps = np.diff(t)
    span = float(t[-1] - t[0])
    tol = NEAR_DUPLICATE * span / (len(t) - 1) if span > 0 else 0.0
    back = np.flatnonzero(steps < 0) + 1  # the sample that comes too early
    repeated = np.flatnonzero((steps >= 0) & (steps <= tol)) + 1
    if not back.size and not repeated.size:
        return
    parts = []
    if repeated.size:
        parts.append(f"{repeated.size} duplicated time stamp(s) (the previous row's time, or within {tol:.3g} s "
                     f"of it) at {_rows_text(repeated, lines)}")
    if back.size:
        parts.append(f"{back.size} decreasing time stamp(s) (before the previous row's) at {_rows_text(back, lines)}")
    k = int(min(repeated[:1].tolist() + back[:1].tolist()))
    fixes = (["drop the repeated rows"] if repeated.size else []) + (
        ["put the rows back in time order (swapped rows, or two logs joined)"] if back.size else [])
    fix = " and ".join(fixes).capitalize()
    raise DataError(f"time must strictly increase; the column has {'; and '.join(parts)}; the "
                    f"first: t = {t[k]:.12g} s after t = {t[k - 1]:.12g} s. {fix}, or fix the "
                    "logger's time stamps", file=file, column=column, row=k + 1)
