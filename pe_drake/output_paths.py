"""Output paths checked before any work (a solve of minutes must not end in a traceback because
``--out`` was read-only), and a reused output folder kept from mixing runs.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable
from pathlib import Path

from pe_drake.exceptions import ConfigError

#: Files ``pe-drake optimize`` writes into its output folder.
OPTIMIZE_OUTPUTS = ("trajectory.json", "trajectory.csv", "trajectory_goal.yaml",
                    "trajectory_goal_bag", "trajectory.png", "playback.html", "report.json",
                    "fitted_capsules.yaml")

#: Files ``pe-drake identify`` writes into its output folder.
IDENTIFY_OUTPUTS = ("identified.json", "residuals.png", "model.urdf", "drive_effects.yaml")

#: Files ``pe-drake diagnose`` writes into its output folder.
DIAGNOSE_OUTPUTS = ("diagnosis.json", "report.md", "torque_heldout.png", "residual_effects.png",
                    "regimes.png", "gap.png", "unexplained.png", "augmented_model.urdf",
                    "augmented_effects.yaml", "augmented_model.json")


def _check_writable_folder(folder: Path, flag: str, target: Path) -> None:
    existing = next((p for p in (folder, *folder.parents) if p.exists()), Path("."))
    if not existing.is_dir():
        raise ConfigError(f"{flag} '{target}': '{existing}' is a file, not a folder")
    try:  # os.access says yes to root even on a read-only file system: try it
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".pe_drake-write-test-")
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ConfigError(f"{flag} '{target}': cannot write in the folder '{existing}' ({err.strerror})") from None


def check_output_dir(path: str | Path, flag: str = "--out") -> Path:
    """Refuses an output folder that is an existing file or cannot be created or written
    (ConfigError naming the flag, the path and what is wrong)."""
    path = Path(path)
    if str(path) == "":
        raise ConfigError(f"{flag} is empty")
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{flag} '{path}' exists and is a file; give a folder")
    _check_writable_folder(path, flag, path)
    return path


def check_output_file(path: str | Path, flag: str, suffixes: Iterable[str] = ()) -> Path:
    """Refuses an output file that is a folder, has the wrong suffix, or cannot be written
    (ConfigError naming the flag, the path and what is wrong)."""
    path = Path(path)
    if path.is_dir() or str(path).endswith(("/", os.sep)):
        raise ConfigError(f"{flag} '{path}' is a folder; give a file name")
    suffixes = tuple(suffixes)
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{flag} '{path}' must end in {' or '.join(suffixes)}")
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"{flag} '{path}' exists and is not writable")
    _check_writable_folder(path.parent, flag, path)
    return path


def output_file(folder: str | Path, name: str) -> Path:
    """``folder/name`` for a result's ``write(folder, name=...)``; ConfigError for a ``folder``
    that names the file itself (``run.write("held.csv")``)."""
    folder = Path(folder)
    suffix = Path(name).suffix.lower()
    if suffix and folder.suffix.lower() == suffix and not folder.is_dir():
        raise ConfigError(f"write() takes the folder and the file's name as name=: got folder '{folder}'; "
                          f"use write('{folder.parent}', name='{folder.name}')")
    return folder / name


def remove_stale_outputs(folder: str | Path, own_names: Iterable[str], written: Iterable[str]) -> list[str]:
    """Deletes the files of ``own_names`` (the command's outputs) in ``folder`` that this run did
    not write (a user's other files stay); returns the names removed."""
    folder = Path(folder)
    keep = set(written)
    removed = []
    for name in own_names:
        path = folder / name
        if name in keep or path.is_symlink():
            continue
        with contextlib.suppress(OSError):
            if path.is_file():
                path.unlink()
                removed.append(name)
            elif path.is_dir():  # a folder output (the goal's bag)
                shutil.rmtree(path)
                removed.append(name)
    return removed
