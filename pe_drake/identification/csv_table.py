"""Reading pe_drake's measurement CSV in bounded memory, every bad line named.

The file is read once, as a stream of lines: each is checked (length, field count) and its line
number kept while numpy's C parser turns chunks of lines into the table of the wanted columns,
so an hour at 1 kHz needs the table and one chunk, not a Python string per line.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from pe_drake import limits
from pe_drake.exceptions import DataError
from pe_drake.identification.csv_checks import (SAVE_AS_UTF8, check_text_file, delimiter_hint,
                                                first_non_number)

#: Lines parsed at once.
CHUNK_LINES = 50_000


def _lines(path: Path, file: str) -> Iterator[tuple[int, str]]:
    """(line number, text) of every line, refusing one longer than ``limits.CSV_LINE``."""
    longest = limits.in_bytes(limits.CSV_LINE)
    with path.open(encoding="utf-8-sig", newline=None) as f:
        lineno = 0
        while True:
            try:
                line = f.readline(longest + 1)
            except UnicodeDecodeError as err:
                raise DataError(f"not UTF-8 text after line {lineno} ({err.reason}); "
                                f"{SAVE_AS_UTF8}", file=file) from None
            if not line:
                return
            lineno += 1
            if len(line) > longest and not line.endswith("\n"):
                raise DataError(f"line {lineno} is longer than {longest:,} characters, "
                                f"{limits.describe(limits.CSV_LINE)}; a measurement line holds one sample", file=file)
            yield lineno, line


def read_header_line(path: Path) -> tuple[int, list[str]]:
    """(line number, column names) of the first non-blank line.

    Raises:
        DataError: no file, an empty file, text that is not UTF-8, a semicolon- or tab-delimited
            header.
    """
    file = str(path)
    problem = limits.input_file_problem(path)
    if problem:
        raise DataError(f"measurement file {problem}", file=file)
    check_text_file(path)  # UTF-16 or another encoding: named, with how to save it
    for lineno, line in _lines(path, file):
        if line.strip():
            delimiter_hint(line, file)  # one column of a ';' or tab file: say so, not "missing columns"
            return lineno, [c.strip().strip('"').strip("'") for c in line.split(",")]
    raise DataError("the file is empty", file=file)


def read_table(path: Path, header_line: int, columns: Sequence[str], wanted: Sequence[str],
               index: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """(table (rows, len(wanted)), all finite; line numbers (rows,)) of the data rows.

    Raises:
        DataError: a line with another field count than the header, a value that is not a
            number or not finite: naming the column, the data row and the line.
    """
    file = str(path)
    usecols = [index[c] for c in wanted]
    # Allocated once at the file's line count: numpy's growing result holds up to 2.4× the table.
    table = np.empty((_count_lines(path), len(wanted)))
    linenos = np.empty(table.shape[0], dtype=np.int64)
    rows, chunk = 0, []

    def flush() -> None:
        nonlocal rows
        try:
            part = np.loadtxt(chunk, delimiter=",", usecols=usecols, ndmin=2, dtype=float, comments=None)
        except ValueError:
            _locate_parse_error(path, header_line, wanted, index)
            raise  # pragma: no cover - _locate_parse_error always raises
        table[rows : rows + len(chunk)] = part
        rows += len(chunk)
        chunk.clear()

    for lineno, line in _lines(path, file):
        if lineno <= header_line or not line.strip():
            continue
        fields = line.count(",") + 1
        if fields != len(columns):
            raise DataError(f"{fields} fields where the header has {len(columns)} (line {lineno} of the file)",
                            file=file, row=rows + len(chunk) + 1)
        linenos[rows + len(chunk)] = lineno
        chunk.append(line)
        if len(chunk) == CHUNK_LINES:
            flush()
    if chunk:
        flush()
    table, rows = table[:rows], linenos[:rows]
    bad = ~np.isfinite(table)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise DataError(f"value '{table[r, c]}' is not a finite number (line {rows[r]} of the file)",
                        file=file, column=wanted[c], row=int(r) + 1)
    return table, rows


def _count_lines(path: Path) -> int:
    """Line breaks in the file, plus one: at least its data rows (np.empty touches no page, so
    the spare rows of blank lines cost nothing)."""
    count = 1
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 24), b""):
            count += block.count(b"\n") + block.count(b"\r") - block.count(b"\r\n")  # \r alone ends one too
    return count


def _locate_parse_error(path: Path, header_line: int, wanted, index) -> None:
    """Slow path after a parse failure: the first field that is not a number, by name."""
    file = str(path)
    rows = ((lineno, line.rstrip("\r\n").split(",")) for lineno, line in _lines(path, file)
            if lineno > header_line and line.strip())
    found = first_non_number(rows, {index[name]: name for name in wanted})
    if found is not None:
        row, lineno, name, raw = found
        raise DataError(f"'{raw}' is not a number (line {lineno} of the file)", file=file,
                        column=name, row=row)
    raise DataError("could not parse the file as comma-separated numbers", file=file)
