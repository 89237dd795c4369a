"""The size limits on files pe_drake reads, so a hostile or broken file cannot hang a run or fill
the memory. Each is overridable by the environment variable its refusal names, e.g.
``PE_DRAKE_MAX_MESH_MB=1024 pe-drake optimize ...``.
"""

from __future__ import annotations

import math
import os
from typing import NamedTuple

from pe_drake.exceptions import ConfigError


class Limit(NamedTuple):
    variable: str  # the environment variable that overrides it
    default: float
    unit: str  # "MB" (2**20 bytes) or "" (a count)
    what: str


MESH = Limit("PE_DRAKE_MAX_MESH_MB", 256, "MB", "a mesh file")
CSV_LINE = Limit("PE_DRAKE_MAX_CSV_LINE_MB", 1, "MB", "a line of a measurement CSV")
HARMONICS = Limit("PE_DRAKE_MAX_HARMONICS", 1000, "", "the harmonics of a trajectory file")
BAG_CHUNK = Limit("PE_DRAKE_MAX_BAG_CHUNK_MB", 256, "MB", "a decompressed chunk of an MCAP bag")
BAG_FILE = Limit("PE_DRAKE_MAX_BAG_FILE_MB", 4096, "MB", "a decompressed storage file of a bag")
BAG_MESSAGE = Limit("PE_DRAKE_MAX_BAG_MESSAGE_MB", 1, "MB", "one message of a bag")
TRAJECTORY = Limit("PE_DRAKE_MAX_TRAJECTORY_MB", 50, "MB", "a trajectory file")


def value(limit: Limit) -> float:
    """The limit in its unit: the environment's value (ConfigError unless positive), or the
    default."""
    text = os.environ.get(limit.variable, "").strip()
    if not text:
        return float(limit.default)
    try:
        number = float(text)
    except ValueError:
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise ConfigError(f"{limit.variable}={text!r}: the limit on {limit.what} must be a positive number"
                          f"{' of ' + limit.unit if limit.unit else ''} (default {limit.default:g})")
    return number


def in_bytes(limit: Limit) -> int:
    """A size limit in bytes."""
    return int(value(limit) * 2**20)


def describe(limit: Limit) -> str:
    """"the 256 MB limit (PE_DRAKE_MAX_MESH_MB raises it)", for a refusal's message."""
    unit = f" {limit.unit}" if limit.unit else ""
    return f"the {value(limit):g}{unit} limit ({limit.variable} raises it)"


def input_file_problem(path) -> str | None:
    """Why ``path`` cannot be read as an input file (reading a named pipe blocks, a device never
    ends), or None."""
    import stat
    from pathlib import Path

    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        return "does not exist" + (" (a broken symbolic link)" if path.is_symlink() else "")
    except OSError as err:
        return f"cannot be read: {err.strerror}"
    if stat.S_ISREG(mode):
        return None
    kind = ("is a folder" if stat.S_ISDIR(mode) else "is a named pipe (FIFO)" if stat.S_ISFIFO(mode)
            else "is a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "is not a regular file")
    return f"{kind}: pe_drake reads regular files only"
