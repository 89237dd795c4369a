"""An output folder's run: one writer at a time, and a manifest that ties its files together.

A command writing a folder holds ``<out>/.pe_drake.lock``, so a second run on it is refused. Its
manifest file lists every other file of the run with its SHA-256 under ``"outputs"`` and is put
in place first: a run killed midway leaves a manifest that no longer matches, and every reader
(:func:`check_output_set`) refuses such a mixed set, naming the file that differs.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import threading
from collections.abc import Iterator
from pathlib import Path

from pe_drake.exceptions import ConfigError, DataError

LOCK_NAME = ".pe_drake.lock"

#: The manifest files pe_drake writes, each listing its run's other files under "outputs".
MANIFESTS = ("report.json", "identified.json", "diagnosis.json", "payload.json")

_held: dict[str, list] = {}  # real path of a locked folder -> [fd, depth]; flock is per open file
_held_guard = threading.Lock()


@contextlib.contextmanager
def output_lock(out: str | Path) -> Iterator[Path]:
    """Holds ``out``'s lock file for the block (re-entrant in one process), creating ``out`` (and
    removing it at the end if the run left it empty).

    Raises:
        ConfigError: another process holds the lock, or the lock file is not a regular file.
    """
    out = Path(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    key = os.path.realpath(out)
    with _held_guard:
        if key in _held:
            _held[key][1] += 1
        else:
            _held[key] = [_acquire(out), 1]
    try:
        yield out
    finally:
        with _held_guard:
            _held[key][1] -= 1
            if _held[key][1] == 0:
                fd = _held.pop(key)[0]
                with contextlib.suppress(OSError):  # unlinked while held: a waiter re-checks the inode
                    os.unlink(out / LOCK_NAME)
                os.close(fd)  # closing the descriptor releases the flock
                if created:
                    with contextlib.suppress(OSError):
                        out.rmdir()  # only when empty: a run refused before writing leaves nothing


def _acquire(out: Path) -> int:
    lock = out / LOCK_NAME
    while True:
        try:  # O_NOFOLLOW: a symlink planted under the lock's name is refused, not followed
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
        except OSError as err:
            if err.errno == errno.ELOOP:
                raise ConfigError(f"'{lock}' is a symbolic link; remove it (pe-drake's lock file is a plain file)") from None
            raise ConfigError(f"cannot create the lock file '{lock}' ({err.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ConfigError(
                f"another pe-drake run is writing to '{out}' (it holds '{lock}'); wait for it to "
                "finish or give another --out") from None
        try:
            if os.stat(lock, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)  # the holder removed the file between our open and our lock: take the new one


def file_digests(folder: Path, exclude: str = "") -> dict[str, str]:
    """{relative path: SHA-256} of every file under ``folder`` except ``exclude``, sorted."""
    digests = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if path.is_file() and name != exclude:
            digests[name] = sha256_of(path)
    return digests


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def add_manifest(folder: Path, manifest: str) -> None:
    """Adds ``"outputs": {name: sha256}`` of the other files in ``folder`` to its JSON ``manifest``."""
    path = folder / manifest
    text = path.read_text()
    data = json.loads(text)
    data["outputs"] = file_digests(folder, exclude=manifest)
    path.write_text(json.dumps(data, indent=2) + ("\n" if text.endswith("\n") else ""))


def check_output_set(path: str | Path) -> None:
    """Refuses ``path`` when a pe_drake manifest beside it (or ``path`` itself) lists it with
    files that are missing or changed; a file no manifest lists is accepted.

    Raises:
        DataError: naming the manifest and the first file that differs.
    """
    path = Path(path)
    for name in MANIFESTS:
        manifest = path.parent / name
        if not manifest.is_file():
            continue
        try:
            listed = json.loads(manifest.read_text()).get("outputs")
        except (OSError, ValueError, AttributeError, RecursionError):
            continue  # not one of ours; the reader of that file says what is wrong with it
        if not isinstance(listed, dict):
            continue
        if path.name != name and path.name not in {other.split("/", 1)[0] for other in listed}:
            continue  # a folder output (a bag) is listed by its files' paths
        for other, digest in listed.items():
            target = path.parent / other
            why = "is missing" if not target.is_file() else "has changed" if sha256_of(target) != digest else ""
            if why:
                raise DataError(
                    f"'{target}' {why} since '{manifest}' recorded the run that wrote this folder "
                    "(the run was interrupted, or another run or a person changed it): re-run the "
                    f"command, or copy '{path.name}' out of the folder to use it alone", file=str(path))
