"""Keeping freed memory for reuse, so each cost evaluation does not fault in fresh pages.

A gradient on G1 allocates and frees dozens of arrays of 0.3–0.7 MB; above glibc's mmap and trim
thresholds each evaluation gets new pages the kernel must fault in and zero.
:func:`reuse_freed_memory` raises both thresholds (called by the solvers, not on import; a no-op
without glibc's ``mallopt``), and :func:`available_bytes` tells what memory is left.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 * 1024 * 1024  # allocations below this come from the heap [bytes]
TRIM_THRESHOLD = 256 * 1024 * 1024  # free heap top kept before returning it [bytes]

_done = False


def reuse_freed_memory() -> bool:
    """Raises glibc's mmap and trim thresholds once per process; False where ``mallopt`` is
    unavailable."""
    global _done
    if _done:
        return True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _done = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _done


def available_bytes() -> int | None:
    """The memory a new allocation can get without swapping: the kernel's MemAvailable, or less
    under a cgroup (container) limit; None where neither can be read (macOS)."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            found += [int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:")]
    except (OSError, ValueError, IndexError):
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f, open("/sys/fs/cgroup/memory.current") as g:
            limit = f.read().strip()
            if limit.isdigit():
                found.append(int(limit) - int(g.read().strip()))
    except (OSError, ValueError):
        pass
    return min(found) if found else None
