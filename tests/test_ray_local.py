"""A local ``--executor ray`` run listens on the loopback interface only (Ray's default is the
machine's address, reachable from the network)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SCRIPT = """
import ray
from pe_drake.excitation.parallel.ray import connect
assert connect("")
print("NODE", ray.nodes()[0]["NodeManagerAddress"])
ray.shutdown()
"""


def test_a_new_local_ray_instance_binds_to_localhost():
    pytest.importorskip("ray")
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    done = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=240)
    assert "NODE 127.0.0.1" in done.stdout, done.stdout + done.stderr
