"""``python -m pe_drake.bench solve``: CPU seconds and cond of one start, old and new formulation.

For each robot (default: G1, UR5 and the two-arm robot of :mod:`pe_drake.bench_models`, loaded
with no config as a user without one would) one start is solved from the same seed with the
formulation before issue 38 (:data:`OLD`) and the default (:data:`NEW`), each timed in CPU
seconds of this process (``time.process_time``: a loaded machine disturbs it far less than wall
time), end to end as ``pe-drake optimize`` runs one start: problem, constraints, program, solve
with its exchange step and re-check, then the quality report of a valid motion. Imports, the
model and the fitted capsules are shared and not timed. Each robot ends with one ``BENCH`` line.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

from pe_drake.bench_models import write_two_arm_lift_urdf
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import build_excitation_program
from pe_drake.excitation.quality import excitation_quality
from pe_drake.excitation.solve import solve_excitation
from pe_drake.multibody.capsule_fitting import fit_capsules
from pe_drake.multibody.registry import resolve_robot_config
from pe_drake.multibody.robot import Robot

#: The robots of ``bench solve`` by default; "two_arm_lift" is :mod:`pe_drake.bench_models`'.
DEFAULT_ROBOTS = ("g1", "ur5", "two_arm_lift")


class Formulation(NamedTuple):
    """How a start is set up: keywords of :func:`build_excitation_program`, IPOPT, the report."""

    program: dict
    ipopt: dict
    quality: dict


#: Before issue 38: the solver in alpha itself, no stall rule, 30 L-BFGS pairs, the quality
#: report on BLAS's own threads.
OLD = Formulation(
    {"limits": "windows", "scaling": "none", "stall": None},
    {"limited_memory_max_history": 30},
    {"one_blas_thread": False},
)
#: The default (issue 38): the stall rule; from 8 harmonics on the solver in harmonic
#: coordinates with 12 L-BFGS pairs; the quality report on one BLAS thread.
NEW = Formulation({}, {}, {})


class Run(NamedTuple):
    """One timed start: the solve, then the quality report of its motion."""

    cpu_s: float  # both [CPU-s]
    solve_cpu_s: float
    quality_cpu_s: float
    cond: float
    nit: int | None
    success: bool
    message: str


def bench_config(robot: str, folder: Path):
    """(config, name) of a bench robot: a built-in's own config, or a model file's defaults
    with capsules fitted to its shapes (as ``pe-drake optimize`` does)."""
    model = str(write_two_arm_lift_urdf(folder)) if robot == "two_arm_lift" else robot
    config = resolve_robot_config(model, None)
    if not config.robot.capsules:
        config, _ = fit_capsules(config, folder)
    return config, Path(model).stem if model != robot else robot


def timed_solve(robot: Robot, config, formulation: Formulation, seed: int, max_iterations: int | None) -> Run:
    """One start of ``config``'s problem in ``formulation`` and the quality report of its
    motion (as ``pe-drake optimize`` reports it), timed in CPU seconds."""
    solver = dataclasses.replace(
        config.solver,
        verbose=False,
        max_iterations=max_iterations or config.solver.max_iterations,
        ipopt_options={**config.solver.ipopt_options, **formulation.ipopt},
    )
    start = time.process_time()
    problem = ExcitationProblem(robot, config.excitation)
    constraints = constraints_from_config(robot, config.excitation, config.environment)
    program = build_excitation_program(problem, constraints, **formulation.program)
    result = solve_excitation(program, solver, problem.initial_guess(seed=seed))
    solved = time.process_time()
    if result.success:  # as optimize_motion: the report of a valid motion
        e = config.excitation
        excitation_quality(problem, result.x, constraints, noise_std=e.noise_std.torque, periods=int(e.periods),
                           **formulation.quality)
    end = time.process_time()
    return Run(end - start, solved - start, end - solved, result.cond, result.nit, result.success, result.message)


def bench_solve(args: argparse.Namespace) -> None:
    """Prints, per robot, the old and new formulation's CPU seconds, cond and a ``BENCH`` line."""
    names = [r for r in args.robots.split(",") if r] if args.robots else list(DEFAULT_ROBOTS)
    if args.robot:  # --robot names one robot
        names = [args.robot]
    with tempfile.TemporaryDirectory(prefix="pe_drake_bench_solve_") as folder:
        for name in names:
            config, label = bench_config(name, Path(folder))
            robot = Robot(label, config.robot)
            runs = {}
            for key, formulation in (("old", OLD), ("new", NEW)):
                runs[key] = r = timed_solve(robot, config, formulation, args.seed, args.max_iterations)
                print(
                    f"{label:14s} {key}  {r.cpu_s:7.2f} CPU-s (solve {r.solve_cpu_s:6.2f}, quality report "
                    f"{r.quality_cpu_s:6.2f})  cond {r.cond:10.4f}  {r.nit} iterations  "
                    f"{'valid' if r.success else 'INVALID'}: {r.message}",
                    flush=True,
                )
            old, new = runs["old"], runs["new"]
            print(
                f"BENCH robot={label} n={robot.n} old_cpu_s={old.cpu_s:.2f} new_cpu_s={new.cpu_s:.2f} "
                f"speedup={old.cpu_s / new.cpu_s:.2f} old_solve_cpu_s={old.solve_cpu_s:.2f} "
                f"new_solve_cpu_s={new.solve_cpu_s:.2f} old_cond={old.cond:.4f} new_cond={new.cond:.4f} "
                f"cond_ratio={new.cond / old.cond:.4f} old_iterations={old.nit} new_iterations={new.nit} "
                f"old_valid={old.success} new_valid={new.success}",
                flush=True,
            )
