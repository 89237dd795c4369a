"""Small file helpers: outputs are written whole or not at all."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


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
