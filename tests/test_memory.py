"""pe_drake.memory: glibc's malloc thresholds raised once per process."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="needs glibc")
def test_thresholds_are_set_once_and_keep_freed_arrays_mapped():
    # In a fresh process: a freed 4 MB array's pages stay with the process (RSS does not drop
    # back) once the thresholds are raised; with glibc's defaults they go back to the kernel.
    code = r"""
import numpy as np, resource, sys
from pe_drake.memory import reuse_freed_memory
def rss_kb():
    return int(open("/proc/self/statm").read().split()[1]) * resource.getpagesize() // 1024
if sys.argv[1] == "reuse":
    assert reuse_freed_memory() and reuse_freed_memory()
before = rss_kb()
a = np.ones(512 * 1024)  # 4 MB, touched
del a
print(rss_kb() - before)
"""
    kept = {}
    for mode in ("reuse", "default"):
        out = subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True, check=True)
        kept[mode] = int(out.stdout.split()[-1])
    assert kept["reuse"] >= 3500, kept  # ~4096 kB still mapped
    assert kept["default"] < 1000, kept  # returned to the kernel on free
