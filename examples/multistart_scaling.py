"""Multi-start scaling: the same starts on 1 and 2 local workers (and on Ray), same results.

Solves ``--starts`` seeded starts of a Panda problem (the built-in config: N = 10, T = 40,
K = 400 with capsule self-collision) at a small IPOPT budget, once per executor setting, and
prints the wall time of each run, the speed-up over the last one-worker run, the best cond,
and how far each start's coefficients are from the first run's (0: bit-identical).

    python examples/multistart_scaling.py --starts 8 --max-iterations 20
    python examples/multistart_scaling.py --starts 8 --max-iterations 20 --ray    # also on a local Ray
    python examples/multistart_scaling.py --repeat 3     # alternate 1 and 2 workers (a shared machine)
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from collections.abc import Sequence

import numpy as np


def run(robot_name: str, starts: int, max_iterations: int, settings: list[tuple[str, int]]) -> list[dict]:
    """One multi-start per (executor, workers) setting; returns a row per setting."""
    from pe_drake.excitation.constraints import constraints_from_config
    from pe_drake.excitation.multistart import MultiStartOptions, solve_multistart
    from pe_drake.excitation.parallel import ExecutorOptions
    from pe_drake.multibody.registry import resolve_robot_config
    from pe_drake.multibody.robot import Robot

    config = resolve_robot_config(robot_name)
    solver = dataclasses.replace(config.solver, max_iterations=max_iterations, verbose=False)
    robot = Robot(robot_name, config.robot)
    seeds = list(range(starts))
    rows, reference = [], None
    for executor, workers in settings:
        begin = time.perf_counter()
        options = MultiStartOptions(seeds, constraints_factory=constraints_from_config,
                                    run=ExecutorOptions(workers=workers, executor=executor))
        ms = solve_multistart(robot, config.excitation, solver, options)
        wall = time.perf_counter() - begin
        reference = reference or ms
        diff = max(float(np.max(np.abs(a.x - b.x))) for a, b in zip(ms.results, reference.results))
        rows.append(
            {
                "executor": ms.executor, "workers": workers, "wall_time_s": wall, "solve_time_s": ms.solve_time,
                "best_cond": ms.best.cond, "best_seed": ms.seed, "max_diff": diff,
                "load_1min": os.getloadavg()[0],
            }
        )
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    import logging

    import pydrake.common  # noqa: F401  (pydrake resets the logger level at import)

    from pe_drake.threads import single_threaded_blas

    logging.getLogger("drake").setLevel(logging.ERROR)
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", default="panda")
    p.add_argument("--starts", type=int, default=8)
    p.add_argument("--max-iterations", type=int, default=20)
    p.add_argument("--ray", action="store_true", help="also run on a local Ray instance with 2 workers")
    p.add_argument("--repeat", type=int, default=1, help="alternate the 1- and 2-worker runs this many times")
    args = p.parse_args(argv)
    settings = [("local", 1), ("local", 2)] * args.repeat + ([("ray", 2)] if args.ray else [])
    if args.ray:
        import ray

        ray.init(num_cpus=2, include_dashboard=False, logging_level="error", log_to_driver=False)
    with single_threaded_blas():
        rows = run(args.robot, args.starts, args.max_iterations, settings)
    print(f"{args.starts} {args.robot} starts, IPOPT <= {args.max_iterations} iterations, {os.cpu_count()} CPUs")
    print(
        "| executor | workers | wall time [s] | speed-up | sum of solve times [s] | best cond (seed) "
        "| max Δalpha vs run 1 [rad] | load |"
    )
    print("|---|---|---|---|---|---|---|---|")
    one = rows[0]["wall_time_s"]
    for r in rows:
        one = r["wall_time_s"] if r["workers"] == 1 else one  # speed-up over the last one-worker run
        print(
            f"| {r['executor']} | {r['workers']} | {r['wall_time_s']:.1f} | {one / r['wall_time_s']:.2f}× | "
            f"{r['solve_time_s']:.1f} | {r['best_cond']:.4g} ({r['best_seed']}) | {r['max_diff']:.1e} | "
            f"{r['load_1min']:.1f} |"
        )
    return 0 if all(r["max_diff"] == 0 for r in rows if r["executor"] != "ray") else 1


if __name__ == "__main__":
    sys.exit(main())
