"""Where IPOPT writes its log files: one folder per process, removed once the process is gone.

IPOPT reports its iteration count only in its log file, which a worker killed mid-solve never
deletes. Each process writes into its own folder ``pe_drake_ipopt_<pid>_*`` and holds a ``flock``
on its ``.lock`` file while it lives (the kernel drops it however the process dies; PIDs are
reused, so none is trusted): a folder whose lock can be taken is an orphan, swept by the
executors when they close and by each process when it makes its folder.
"""

from __future__ import annotations

import atexit
import contextlib
import multiprocessing.util
import os
import shutil
import tempfile
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no flock; orphans stay until removed by hand
    fcntl = None

PREFIX = "pe_drake_ipopt_"
#: Age after which a folder without a lock file (a process killed while making it) is removed [s].
UNLOCKED_AGE_S = 60.0

_own: dict = {}  # this process's folder: {"pid", "folder", "fd"}


def log_folder() -> Path:
    """This process's folder for IPOPT logs (made, and locked, on first use)."""
    if _own.get("pid") == os.getpid() and _own["folder"].is_dir():
        return _own["folder"]
    remove_orphaned_log_folders()
    root = Path(tempfile.gettempdir())
    # Made under a name the sweep ignores, locked, then renamed: a sweep never sees it unlocked.
    staging = Path(tempfile.mkdtemp(prefix=f".{PREFIX}", dir=root))
    fd = os.open(staging / ".lock", os.O_CREAT | os.O_RDWR, 0o600)
    if fcntl is not None:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    folder = root / f"{PREFIX}{os.getpid()}_{staging.name.removeprefix('.' + PREFIX)}"
    os.rename(staging, folder)
    _own.update(pid=os.getpid(), folder=folder, fd=fd)
    # A pool worker ends with os._exit (no atexit) after running multiprocessing's finalizers.
    multiprocessing.util.Finalize(None, _remove_own, exitpriority=0)
    return folder


def new_log_file() -> Path:
    """A new, empty log file in :func:`log_folder` (the caller deletes it after reading it)."""
    fd, name = tempfile.mkstemp(prefix="ipopt_", suffix=".log", dir=log_folder())
    os.close(fd)
    return Path(name)


def remove_orphaned_log_folders(root: str | Path | None = None) -> list[Path]:
    """Removes the log folders of processes that are gone from ``root`` (default: the system
    temporary folder); returns the folders removed."""
    if fcntl is None:  # pragma: no cover
        return []
    root = Path(root or tempfile.gettempdir())
    removed = []
    for folder in root.glob(f"{PREFIX}*"):
        with contextlib.suppress(OSError):
            if folder.is_symlink() or not folder.is_dir() or folder.stat().st_uid != os.getuid():
                continue  # only our own folders
            if folder == _own.get("folder") and _own.get("pid") == os.getpid():
                continue
            if _orphaned(folder):
                shutil.rmtree(folder, ignore_errors=True)
                removed.append(folder)
    return removed


def _orphaned(folder: Path) -> bool:
    try:
        fd = os.open(folder / ".lock", os.O_RDWR)
    except FileNotFoundError:
        return time.time() - folder.stat().st_mtime > UNLOCKED_AGE_S
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False  # its process holds the lock: alive
    finally:
        os.close(fd)
    return True


def _remove_own() -> None:
    if _own.get("pid") != os.getpid():
        return
    shutil.rmtree(_own["folder"], ignore_errors=True)
    with contextlib.suppress(OSError):
        os.close(_own["fd"])
    _own.clear()


def _forget_in_child() -> None:
    # A forked child has its own pid and makes its own folder; closing the inherited
    # descriptor does not release the parent's lock (the parent still holds its own).
    fd = _own.get("fd")
    _own.clear()
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)


atexit.register(_remove_own)
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_child)
