"""Benchmarks that print numbers: ``python -m pe_drake.bench {gradient,identify,diagnose}``.

Each benchmark prints its measurements and ends with one line ``BENCH key=value ...`` so
scripts can collect it. Timings are wall-clock medians of repeated runs on this machine.
"""

from __future__ import annotations

import argparse
import importlib
import math
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

# name -> (module, function): each function takes the parsed args and prints its results.
_BENCHMARKS = {
    "gradient": ("pe_drake.bench", "bench_gradient"),
    "identify": ("pe_drake.identify_commands", "bench_identify"),
    "diagnose": ("pe_drake.diagnosis", "bench_diagnose"),
}


def median_time(
    function: Callable[[], object], repeats: int = 7, warmup: int = 1, warmup_seconds: float = 1.0
) -> float:
    """Median wall time of ``function()`` over ``repeats`` runs [s], in steady state.

    Runs it ``warmup`` times and for at least ``warmup_seconds`` first: a solver calls the
    cost hundreds of times in a row, and the first calls pay for cold caches and a CPU that
    has not yet raised its clock (measured here: up to 2× slower over the first 0.2 s).
    """
    start = time.perf_counter()
    done = 0
    while done < warmup or time.perf_counter() - start < warmup_seconds:
        function()
        done += 1
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def bench_gradient(args: argparse.Namespace) -> None:
    """The paper's problem size: G1's 14 arm joints, N = 10, ω = π/4, T = 40 samples 0.2 s
    apart (294 variables). Times one cost evaluation, one analytic gradient (value and
    gradient from scratch), one forward finite-difference gradient, and their difference.
    Runs as the solvers do: one BLAS thread, freed memory kept for reuse
    (:mod:`pe_drake.memory`; ``--default-malloc`` leaves glibc's defaults)."""
    from pe_drake.config import ExcitationConfig
    from pe_drake.excitation import ExcitationProblem
    from pe_drake.memory import reuse_freed_memory
    from pe_drake.robot import load_robot
    from pe_drake.threads import single_threaded_blas

    reused = False if args.default_malloc else reuse_freed_memory()

    robot = load_robot(args.robot)
    config = ExcitationConfig(harmonics=10, omega=math.pi / 4, cost_samples=40)
    problem = ExcitationProblem(robot, config)
    rng = np.random.default_rng(args.seed)
    alpha = problem.initial_guess(seed=args.seed, amplitude=0.3)
    alpha += 1e-9 * rng.normal(size=alpha.shape)
    with single_threaded_blas():
        cost_s = median_time(lambda: problem.value(alpha), repeats=args.repeats)

        def analytic():
            problem._cache_key = None  # no caching: value + gradient from scratch
            return problem.evaluate(alpha).grad

        grad_s = median_time(analytic, repeats=args.repeats)
        grad = analytic()
        h = 1e-6

        def forward_difference():
            f0 = problem.value(alpha)
            out = np.empty_like(alpha)
            for i in range(len(alpha)):
                x = alpha.copy()
                step = h * max(1.0, abs(x[i]))
                x[i] += step
                out[i] = (problem.value(x) - f0) / step
            return out

        fd_s = median_time(forward_difference, repeats=1, warmup=0, warmup_seconds=0.0)
        # Accuracy against central differences (forward ones carry O(h) error).
        central = np.empty_like(alpha)
        for i in range(len(alpha)):
            x1, x2 = alpha.copy(), alpha.copy()
            step = h * max(1.0, abs(alpha[i]))
            x1[i] += step
            x2[i] -= step
            central[i] = (problem.value(x1) - problem.value(x2)) / (2 * step)
    rel_err = float(np.linalg.norm(grad - central) / np.linalg.norm(central))
    print(f"robot {robot.name}: n = {robot.n}, N = 10, T = 40, variables = {problem.num_variables}, "
          f"base parameters = {problem.base.count}, cond = {problem.value(alpha):.4g}; "
          f"freed memory {'reused' if reused else 'returned (glibc defaults)'}")
    print(f"one cost evaluation            {cost_s * 1e3:9.2f} ms")
    print(f"one analytic gradient          {grad_s * 1e3:9.2f} ms  (value + gradient, = {grad_s / cost_s:.2f} cost evaluations)")
    print(f"one forward-difference gradient {fd_s * 1e3:8.1f} ms  ({problem.num_variables + 1} cost evaluations)")
    print(f"speed-up fd / analytic         {fd_s / grad_s:9.1f} x   (paper: 89 x)")
    print(f"relative error vs central differences {rel_err:.2e}   (paper: 1.3e-5)")
    print(f"BENCH cost_ms={cost_s * 1e3:.3f} grad_ms={grad_s * 1e3:.3f} fd_ms={fd_s * 1e3:.1f} rel_err={rel_err:.3e}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pe_drake.bench", description=__doc__)
    parser.add_argument("benchmark", choices=sorted(_BENCHMARKS))
    parser.add_argument("--robot", default=None, help="robot (default: g1 for gradient, panda otherwise)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=51, help="timed runs per median (default: %(default)s)")
    parser.add_argument(
        "--default-malloc", action="store_true", help="gradient: keep glibc's malloc thresholds (see pe_drake.memory)"
    )
    args = parser.parse_args(argv)
    if args.robot is None:
        args.robot = "g1" if args.benchmark == "gradient" else "panda"
    module, function = _BENCHMARKS[args.benchmark]
    getattr(importlib.import_module(module), function)(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
