"""Small file helpers: outputs are written whole or not at all; JSON inputs are read with a
nesting limit."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pe_drake.exceptions import DataError

#: Deepest nesting of arrays and objects accepted in a JSON input (pe_drake writes 4 at most).
MAX_JSON_NESTING = 100


def atomic_write_text(path: str | Path, text: str) -> None:
    """Writes ``text`` to a temporary file beside ``path`` and renames it into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def staged_output_dir(out: str | Path) -> Iterator[Path]:
    """A temporary folder whose files are moved into ``out`` only if the block succeeds.

    Usage::

        with staged_output_dir(out) as tmp:
            write(tmp / "a.json"); write(tmp / "b.csv")
        # now out/a.json and out/b.csv exist; on an exception neither does.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out, prefix=".staging-"))
    try:
        yield tmp
        for item in tmp.iterdir():
            if item.is_file():
                os.chmod(item, 0o666 & ~_umask())
            target = out / item.name
            if item.is_dir() and target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)  # a folder output (a bag) of an earlier run: replaced whole
            os.replace(item, target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def loads_json(text: str, file: str) -> Any:
    """``json.loads(text)``, refusing nesting deeper than :data:`MAX_JSON_NESTING`.

    Python's decoder recurses per level (100000 ``[`` is a RecursionError traceback), and a
    structure parsed a few hundred levels deep still breaks the code that walks it.

    Raises:
        DataError: "nested too deeply", naming ``file``.
        json.JSONDecodeError: as ``json.loads``.
    """
    too_deep = DataError(f"nested too deeply (more than {MAX_JSON_NESTING} levels of arrays or objects)", file=file)
    try:
        data = json.loads(text)
    except RecursionError:
        raise too_deep from None
    stack = [(data, 1)]
    while stack:  # a stack, not recursion: the depth is what is checked
        value, depth = stack.pop()
        if isinstance(value, (list, dict)):
            if depth > MAX_JSON_NESTING:
                raise too_deep
            stack += [(v, depth + 1) for v in (value.values() if isinstance(value, dict) else value)]
    return data
