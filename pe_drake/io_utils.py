"""File helpers: outputs are written whole or not at all; JSON inputs have a nesting limit."""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from pe_drake.exceptions import DataError
from pe_drake.output_paths import remove_stale_outputs
from pe_drake.output_set import add_manifest, output_lock

#: Name prefix of the folder a run is staged in inside its output folder.
STAGING_PREFIX = ".staging-"
#: Deepest nesting of arrays and objects accepted in a JSON input (pe_drake writes 4 at most).
MAX_JSON_NESTING = 100


def atomic_write_text(path: str | Path, text: str) -> None:
    """Writes ``text`` to ``path`` whole or not at all (:func:`atomic_write`)."""
    atomic_write(path, lambda f: f.write(text))


def atomic_write(path: str | Path, write: Callable[[IO], object], binary: bool = False,
                 suffix: str = ".tmp") -> Path:
    """Calls ``write(file)`` on a new file beside ``path``, then renames it into place.

    The file's name is unpredictable and it is created exclusively, so a symlink planted at a
    temporary name cannot redirect the write.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
    try:
        with os.fdopen(fd, "wb" if binary else "w") as f:
            write(f)
        chmod_as_created(tmp)  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    return path


def finite_json(value: Any) -> Any:
    """``value`` with inf and NaN as None (not JSON), numpy values as Python numbers and lists."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if hasattr(value, "tolist"):  # numpy array or scalar
        return finite_json(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


class Terminated(BaseException):
    """SIGTERM arrived: raised so that every ``finally`` runs, as for Ctrl-C (a BaseException,
    like KeyboardInterrupt: no ``except Exception`` swallows it)."""


@contextlib.contextmanager
def terminated_as_exception() -> Iterator[None]:
    """Within it, SIGTERM raises :class:`Terminated` in this process, so staged outputs and the
    lock are cleaned up as on an exception. A forked worker keeps the default action: it has
    nothing of ours to clean and its pool expects it to die."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return
    owner = os.getpid()

    def handler(_signum, _frame):
        if os.getpid() != owner:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def chmod_as_created(path: str | Path) -> None:
    """Gives a staged output the mode ``open``/``mkdir`` would have (0666/0777 less the umask),
    not ``mkstemp``'s 0600."""
    umask = os.umask(0)  # reading the umask sets it: set it back
    os.umask(umask)
    os.chmod(path, (0o777 if Path(path).is_dir() else 0o666) & ~umask)


@contextlib.contextmanager
def staged_output_dir(out: str | Path, manifest: str = "", own_names: Iterable[str] = ()) -> Iterator[Path]:
    """A temporary folder whose files are moved into ``out`` only if the block succeeds.

    Args:
        manifest: the run's JSON file that gets ``"outputs"``, the SHA-256 of every other file
            (:mod:`pe_drake.output_set`). The previous run's files of the same names are moved
            out first, then the manifest in, then the other files: a run killed at any point
            leaves no old file beside a new one.
        own_names: every name the command may write: those this run did not write are removed;
            other files in ``out`` are left alone.
    """
    out = Path(out)
    with output_lock(out):
        for stale in out.glob(STAGING_PREFIX + "*"):  # left by a killed run: only the lock holder stages
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale, ignore_errors=True)
        tmp = Path(tempfile.mkdtemp(dir=out, prefix=STAGING_PREFIX))
        try:
            yield tmp
            for item in tmp.rglob("*"):
                if item.is_file():
                    chmod_as_created(item)
            written = sorted(item.name for item in tmp.iterdir())
            if manifest in written:
                add_manifest(tmp, manifest)
            # The previous run's files leave before the new manifest arrives, each by one rename:
            # a controller reading the goal, bag or URDF never sees old beside new (the manifest
            # alone only protects pe_drake's own readers).
            _retire(out, tmp / ".retired", [n for n in written if n != manifest])
            remove_stale_outputs(out, own_names, written)
            if manifest in written:
                os.replace(tmp / manifest, out / manifest)
            for name in written:
                if name == manifest:
                    continue
                item, target = tmp / name, out / name
                if item.is_dir() and target.is_dir() and not target.is_symlink():
                    shutil.rmtree(target)  # a folder output (a bag) of an earlier run: replaced whole
                os.replace(item, target)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


def _retire(out: Path, bin_: Path, names: Iterable[str]) -> None:
    """Moves ``out/<name>`` (a file, a folder or a link, not followed) into ``bin_``, each whole."""
    bin_.mkdir()
    for name in names:
        if os.path.lexists(out / name):
            os.replace(out / name, bin_ / name)


def final_folder(path: str | Path) -> Path:
    """The folder a file written at ``path`` ends up in (``out`` for one staged in
    ``out/.staging-*``)."""
    parent = Path(path).parent
    return parent.parent if parent.name.startswith(STAGING_PREFIX) else parent


def portable_path(target: str | Path, folder: str | Path) -> str:
    """``target`` relative to ``folder``, so that a shared output carries no user name or folder
    layout; a ``package://`` URI or a built-in name is kept as it is."""
    text = str(target)
    if not text or "://" in text or not os.path.isabs(text):
        return text
    return os.path.relpath(os.path.realpath(text), os.path.realpath(folder))


def portable_config(data: dict, folder: str | Path) -> dict:
    """A report's JSON dict with the config's model, capsule, package and prior paths made
    relative to ``folder`` (:func:`portable_path`)."""
    robot = (data.get("config") or {}).get("robot")
    if isinstance(robot, dict):
        for key in ("model", "capsules"):
            if isinstance(robot.get(key), str):
                robot[key] = portable_path(robot[key], folder)
        if isinstance(robot.get("packages"), dict):
            robot["packages"] = {k: portable_path(v, folder) for k, v in robot["packages"].items()}
    for key in ("prior", "fitted_capsules"):
        value = data.get(key)
        if isinstance(value, list):
            data[key] = [portable_path(v, folder) if isinstance(v, str) else v for v in value]
        elif isinstance(value, str):
            data[key] = portable_path(value, folder)
    return data


def describe_write_error(err: OSError) -> str:
    """An OSError as one line: what happened to which file, and for a full disk what to do."""
    where = f" '{err.filename}'" if err.filename else ""
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"no space left on the device to write{where} ({err.strerror}); free some space and re-run"
    return f"{err.strerror or err}{':' if where else ''}{where}"


def loads_json(text: str, file: str) -> Any:
    """``json.loads(text)``, refusing nesting deeper than :data:`MAX_JSON_NESTING` (Python's
    decoder and the code that walks the result recurse per level).

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
