"""Input files that are not regular files (issue 34): a named pipe or a device given as
``--data``, ``--config``, ``--robot``, ``--model`` or a trajectory is refused at once, naming
what it is, instead of blocking on the pipe or being called missing. Each command runs in a
child process limited to 30 s and 1 GB, so a regression fails instead of hanging the suite."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BOUNDED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2**30, 2**30))
from pe_drake.cli import main
sys.exit(main(sys.argv[1:]))
"""


def run_bounded(argv: list[str], cwd: Path, seconds: float = 30) -> subprocess.CompletedProcess:
    """``pe-drake argv`` in a child limited to 1 GB of address space and ``seconds``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-c", BOUNDED, *argv], capture_output=True, text=True,
                          timeout=seconds, env=env, cwd=cwd)


@pytest.mark.parametrize("argv, named", [
    (["identify", "--robot", "panda", "--data", "{fifo}.csv", "--out", "out"], "named pipe"),
    (["optimize", "--robot", "panda", "--config", "{fifo}.yaml", "--out", "out"], "named pipe"),
    (["optimize", "--robot", "{fifo}.urdf", "--out", "out"], "named pipe"),
    (["view", "{fifo}.json", "--html", "p.html"], "named pipe"),
    (["validate", "--robot", "panda", "--model", "{fifo}.json", "--data", "{fifo}.csv"], "named pipe"),
    (["identify", "--robot", "panda", "--data", "{zero}.csv", "--out", "out"], "is a device"),
])
def test_pipes_and_devices_as_inputs_are_named(tmp_path, argv, named):
    for suffix in (".csv", ".yaml", ".urdf", ".json"):
        os.mkfifo(tmp_path / f"pipe{suffix}")
        os.symlink("/dev/zero", tmp_path / f"zero{suffix}")
    argv = [a.format(fifo=tmp_path / "pipe", zero=tmp_path / "zero") for a in argv]
    done = run_bounded(argv, tmp_path)
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr, done.stderr


def _anchors(indent: str, levels: int) -> str:
    """``levels`` anchors, each a list of ten aliases of the one before: 10^levels values."""
    rows = [f"{indent}l0: &b0 [1, 2, 3]"]
    rows += [f"{indent}l{k}: &b{k} [{', '.join([f'*b{k - 1}'] * 10)}]" for k in range(1, levels)]
    return "\n".join(rows) + "\n"


@pytest.mark.parametrize("text, message", [
    (_anchors("", 25), "expand to"),  # under unknown top-level keys
    ("robot:\n  model: x.urdf\n  support_points:\n" + _anchors("    ", 25), "expand to"),  # as values
    ("robot: &r\n  joints: [*r]\n", "cycle"),
    ("solver:\n  max_iterations: 10\nexcitation:\n  harmonics: 3\nsolver:\n  max_iterations: 20\n",
     "line 5: key 'solver' is given twice"),
    ("robot:\n  joints: [a]\n  joints: [b]\n", "line 3: key 'joints' is given twice"),
])
def test_yaml_alias_bombs_and_repeated_keys_are_refused(tmp_path, text, message):
    """Linear in the file's size: each refused in well under the child's 30 s."""
    (tmp_path / "c.yaml").write_text(text)
    done = run_bounded(["optimize", "--robot", "panda", "--config", "c.yaml", "--out", "out"], tmp_path)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and "c.yaml" in done.stderr, done.stderr
