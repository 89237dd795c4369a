"""``python -m pe_drake.bench memory``: peak memory and time of ``identify``, ``validate`` and
``diagnose`` on Panda logs of ``--minutes`` at 1 kHz, each command in its own CLI process (its
peak is that process's maximum resident set size).
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pe_drake.bench import bench_trajectory
from pe_drake.multibody.drive_columns import coulomb_column
from pe_drake.multibody.robot import load_robot
from pe_drake.simulation.synthetic import model_measurement

#: The harness a command runs in: its child's peak RSS [kB] on the last line.
_PEAK = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]).returncode; "
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); sys.exit(r)")


def write_long_log(path: str | Path, minutes: float, *, rate_hz: float = 1000.0, seed: int = 0,
                   robot_name: str = "panda") -> int:
    """Writes a ``minutes``-long log (t, q, tau) of a periodic motion with friction and fresh
    noise per period, one period at a time; returns the rows written."""
    robot = load_robot(robot_name)
    trajectory = bench_trajectory(robot, seed)
    period = 2 * math.pi / trajectory.omega
    one = model_measurement(robot, trajectory, rate_hz=rate_hz, duration=period)
    keep = one.t < period - 0.5 / rate_hz
    t, q, v = one.t[keep], one.q[keep], one.v[keep]
    tau = one.tau[keep] + 0.8 * coulomb_column(v, 0.02) + 0.3 * v  # friction: diagnose has something to name
    rng = np.random.default_rng(seed)
    header = ",".join(["t"] + [f"q.{j}" for j in robot.joint_names] + [f"tau.{j}" for j in robot.joint_names])
    rows = 0
    with open(path, "w") as f:
        f.write(header + "\n")
        for k in range(math.ceil(minutes * 60.0 / period)):
            noisy = tau + 0.05 * rng.standard_normal(tau.shape)
            np.savetxt(f, np.column_stack([t + k * period, q, noisy]), fmt="%.10g", delimiter=",")
            rows += len(t)
    return rows


def peak_of(argv: list[str]) -> tuple[float, float, int]:
    """(peak resident memory [MB], wall time [s], exit code) of ``pe-drake argv`` in a new
    process."""
    start = time.perf_counter()
    command = [sys.executable, "-c", _PEAK, sys.executable, "-c", "import sys; from pe_drake.cli import main; "
               "sys.exit(main(sys.argv[1:]))", *argv]
    done = subprocess.run(command, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    lines = done.stdout.strip().splitlines()
    peak_kb = float(lines[-1]) if lines and lines[-1].strip().isdigit() else float("nan")
    if done.returncode:
        sys.stderr.write(done.stderr[-2000:])
    return peak_kb / 1e3, seconds, done.returncode


def bench_memory(args) -> None:
    minutes = [float(m) for m in str(args.minutes).split(",")]
    print(f"{'log':>8s} {'rows':>10s} {'CSV MB':>8s} | {'command':8s} {'peak MB':>8s} {'time s':>7s}")
    results, peaks = [], {}
    with tempfile.TemporaryDirectory(prefix="pe_drake-bench-memory-") as tmp:
        for m in minutes:
            log = Path(tmp) / f"panda_{m:g}min.csv"
            rows = write_long_log(log, m, seed=args.seed)
            size = log.stat().st_size / 1e6
            model = Path(tmp) / f"id_{m:g}"
            runs = {
                "identify": ["identify", "--robot", "panda", "--data", str(log), "--out", str(model)],
                "validate": ["validate", "--robot", "panda", "--model", str(model / "identified.json"), "--data", str(log)],
                "diagnose": ["diagnose", "--robot", "panda", "--data", str(log), "--out", str(Path(tmp) / f"dg_{m:g}")],
            }
            for name, argv in runs.items():
                peak, seconds, code = peak_of(argv)
                status = "" if code == 0 else f"  exit {code}"
                print(f"{m:>6g} m {rows:>10d} {size:>8.0f} | {name:8s} {peak:>8.0f} {seconds:>7.1f}{status}", flush=True)
                if code == 0:
                    peaks.setdefault(name, []).append((rows, peak))
                results.append(f"{name}_{m:g}min_mb={peak:.0f} {name}_{m:g}min_s={seconds:.1f}")
            log.unlink()
    for name, points in peaks.items():
        if len(points) > 1:
            (r0, p0), (r1, p1) = points[0], points[-1]
            print(f"{name}: {1e6 * (p1 - p0) / (r1 - r0):.0f} B per 1 kHz row above {p0:.0f} MB")
    print("BENCH " + " ".join(results))
