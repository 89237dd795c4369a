"""Keeping freed memory for reuse, so each cost evaluation does not fault in fresh pages.

One gradient of the excitation cost on G1 allocates a few dozen arrays of 0.3–0.7 MB and
frees them again. glibc maps allocations above its mmap threshold straight from the kernel
and hands freed heap tops back above its trim threshold; either way the next evaluation gets
new pages, which the kernel must fault in and zero. On the 2-core VM we measure on, that was
a third of the time (``python -m pe_drake.bench gradient``: value 6.5–8.4 → 4.2–5.3 ms,
value + gradient 13.3–16.0 → 8.7–11.1 ms, three interleaved runs each).

:func:`reuse_freed_memory` raises both thresholds once per process (at most a few hundred
MB stay mapped after a solve). It is called by the solvers and the benchmark, not on import,
so importing pe_drake changes nothing; it does nothing where glibc's ``mallopt`` is missing
(macOS, musl).
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
    """Raises glibc's mmap and trim thresholds once per process.

    Returns:
        True if the thresholds are set (now or by an earlier call), False where ``mallopt``
        is unavailable.
    """
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
