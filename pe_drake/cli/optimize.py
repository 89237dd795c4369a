"""``pe-drake optimize``: from a robot to an optimized exciting trajectory on disk."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from pe_drake.cli.common import config_from_args, robot_from_args
from pe_drake.config import Config, noise_vector, validate_config
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.fourier import FourierBasis, sample_times
from pe_drake.excitation.multistart import solve_multistart
from pe_drake.excitation.parallel import open_executor
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.quality import QualityReport, excitation_quality
from pe_drake.excitation.trajectory_file import load_trajectory, save_trajectory, write_trajectory_csv
from pe_drake.io_utils import staged_output_dir
from pe_drake.plots import plot_trajectory
from pe_drake.viewer import write_playback_html


def prior_regressor(problem, trajectory_json: str | Path) -> np.ndarray:
    """Stacked base regressor of an earlier motion (for C0, Eq. 41), at the problem's number
    of cost samples over that motion's own period.

    Raises:
        DataError: the file's joints differ from the robot's.
    """
    trajectory, data = load_trajectory(trajectory_json)
    joints = tuple(data["joints"])
    if joints != problem.robot.joint_names:
        raise DataError(
            f"its joints {list(joints)} differ from the robot's {list(problem.robot.joint_names)}",
            file=str(trajectory_json),
        )
    basis = FourierBasis(trajectory.harmonics, trajectory.omega, sample_times(trajectory.period, problem.config.cost_samples))
    q, v, vd = basis.q(trajectory.a, trajectory.b, trajectory.q0), basis.v(trajectory.a, trajectory.b), basis.vd(
        trajectory.a, trajectory.b
    )
    Y = problem.rows(q, v, vd)  # the measurement's rows (joint torques, ground wrench or both)
    return problem.base.reduce(Y).reshape(-1, problem.base.count)


def _apply_arguments(config: Config, args: argparse.Namespace) -> Config:
    if args.solver:
        config.solver.name = args.solver
    if args.criterion:
        config.excitation.criterion = args.criterion
    if args.max_iterations is not None:
        config.solver.max_iterations = args.max_iterations
    if args.seed is not None:
        config.excitation.seed = args.seed
    if getattr(args, "measurement", None):
        config.excitation.measurement = args.measurement
    if args.quiet:
        config.solver.verbose = False
    if args.starts is not None:
        config.parallel.starts = args.starts
    if args.workers is not None:
        if args.workers < 1:
            raise ConfigError(f"--workers must be a positive integer, got {args.workers}")
        config.parallel.workers = args.workers
    if args.executor:
        config.parallel.executor = args.executor
    if args.ray_address:
        config.parallel.executor = args.executor or "ray"
        config.parallel.address = args.ray_address
    return validate_config(config)


def optimize_command(args: argparse.Namespace) -> int:
    """Runs ``pe-drake optimize``; returns 0 on success, 1 if no valid trajectory was found."""
    if not args.csv_rate > 0 or not math.isfinite(args.csv_rate):
        raise ConfigError(f"--csv-rate must be a positive number [Hz], got {args.csv_rate}")
    config = config_from_args(args, lambda c: _apply_arguments(c, args))
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, flush=True))
    start = time.perf_counter()
    robot = robot_from_args(args, config)
    noise_vector(config.excitation.noise_std.torque, robot.joint_names)  # refuse a bad noise_std before solving
    say(f"robot {robot.name}: {robot.n} excited joints, {robot.num_bodies} moving bodies")
    problem = _problem(robot, config, args.prior, say)
    constraints = constraints_from_config(robot, config.excitation)
    if constraints:
        say("constraints: joint limits, " + ", ".join(c.name for c in constraints))
    ms = _solve_starts(robot, problem, config, say)
    result = ms.best
    say(
        f"{'success' if result.success else 'FAILED'}: {result.message}; cond {result.cond:.5g} "
        f"(this motion alone {result.cond_motion:.5g}), seed {ms.seed}, "
        f"{result.nit if result.nit is not None else '-'} iterations, {result.nfev} evaluations, {result.wall_time:.1f} s"
    )
    say("minimum margins at 1 kHz: " + ", ".join(f"{k} {m:.4g}" for k, m in result.margins.items()))
    quality = _quality(problem, result, constraints, config) if result.success else None
    for line in quality.summary_lines() if quality is not None else []:
        say(line)

    report = _report(robot, problem, config, ms, args.prior, time.perf_counter() - start)
    report["quality"] = quality.to_dict() if quality is not None else None
    out = Path(args.out)
    with staged_output_dir(out) as tmp:
        if result.success:
            _write_success_outputs(tmp, robot, result, args, say, quality)
        (tmp / "report.json").write_text(json.dumps(report, indent=2, default=float))
    if not result.success:
        print(
            f"pe-drake optimize: no valid trajectory: {result.message}. Only {out / 'report.json'} was "
            "written. Try more iterations (--max-iterations), more starts (--starts), another seed (--seed), "
            "or looser margins.",
            file=sys.stderr,
        )
        return 1
    say(f"wrote {out}/trajectory.json, trajectory.csv, report.json, trajectory.png" + ("" if args.no_html else ", playback.html"))
    return 0


def _quality(problem, result, constraints, config: Config) -> QualityReport:
    """The quality figures of the optimized motion (issue 13), for ``excitation.periods``
    periods when the config has that setting (else one)."""
    periods = int(getattr(config.excitation, "periods", 1))
    return excitation_quality(problem, result.x, constraints, noise_std=config.excitation.noise_std.torque, periods=periods)


def _problem(robot, config: Config, priors: list[str], say):
    """The excitation problem, with the prior motions' regressors as C0 (Eq. 41)."""
    problem = ExcitationProblem(robot, config.excitation)
    if priors:
        blocks = [prior_regressor(problem, p) for p in priors]
        problem = ExcitationProblem(robot, config.excitation, C0=np.vstack(blocks), base=problem.base, model=problem.model)
        say(f"prior data: {len(priors)} motion(s), {problem.C0.shape[0]} rows, cond(C0) = {np.linalg.cond(problem.C0):.4g}")
    say(
        f"{problem.base.count} base parameters of the {config.excitation.measurement} rows; {problem.num_variables} variables "
        f"(N = {problem.harmonics}, ω = {problem.omega:.4g} rad/s, period {problem.period:.3g} s); "
        f"T = {config.excitation.cost_samples} cost samples, K = {config.excitation.constraint_samples} constraint samples"
    )
    return problem


def _solve_starts(robot, problem, config: Config, say):
    """Multi-start (start k: seed + k) on the configured executor; the best feasible start is kept."""
    par = config.parallel
    seeds = [config.excitation.seed + k for k in range(par.starts)]
    executor = open_executor(
        robot,
        par.executor,
        par.workers or None,
        tasks=par.starts,
        address=par.address,
        base=problem.base,
        constraints_factory=constraints_from_config,
    )
    with executor:
        where = "in this process" if executor.name == "main" else f"on {executor.workers} {executor.name} worker(s)"
        say(
            f"solving {par.starts} start(s) (seeds {seeds[0]}..{seeds[-1]}) {where} with {config.solver.name} "
            f"(max {config.solver.max_iterations} iterations) ..."
        )

        def progress(event) -> None:
            if event.kind != "progress" or config.solver.verbose:
                say(str(event))

        return solve_multistart(
            None, config.excitation, config.solver, seeds, C0=problem.C0, executor=executor, progress=progress
        )


def _report(robot, problem, config: Config, ms, priors: list[str], total_time: float) -> dict:
    result = ms.best
    return {
        "robot": robot.name,
        "success": result.success,
        "message": result.message,
        "status": result.status,
        "solver": result.solver,
        "criterion": config.excitation.criterion,
        "measurement": config.excitation.measurement,
        "cond": result.cond,
        "cond_motion": result.cond_motion,
        "criterion_value": result.fun,
        "iterations": result.nit,
        "evaluations": result.nfev,
        "seed": ms.seed,
        "solve_time_s": result.wall_time,
        "multistart_time_s": ms.wall_time,
        "total_time_s": total_time,
        "executor": {"name": ms.executor, "workers": ms.workers, "address": config.parallel.address},
        "starts": [
            {"seed": s.seed, "cond": s.cond, "success": s.success, "time_s": s.wall_time, "task_time_s": s.task_time,
             "worker": s.worker, "criterion_value": s.fun, "message": s.message}
            for s in ms.starts
        ],
        "margins_1khz": result.margins,
        "base_parameters": problem.base.count,
        "base_parameter_names": list(problem.base.base_names),
        "singular_values": result.singular_values.tolist(),
        "prior": [str(p) for p in priors],
        "config": dataclasses.asdict(config),
    }


def _write_success_outputs(tmp: Path, robot, result, args, say, quality: QualityReport | None = None) -> None:
    save_trajectory(tmp / "trajectory.json", robot, result.trajectory, cond=result.cond, cond_motion=result.cond_motion)
    write_trajectory_csv(tmp / "trajectory.csv", robot.joint_names, result.trajectory, args.csv_rate)
    plot_trajectory(
        tmp / "trajectory.png",
        robot,
        result.trajectory,
        result.singular_values,
        title=f"{robot.name}: cond {result.cond:.4g}",
        note=quality.figure_note() if quality is not None else "",
    )
    if not args.no_html:
        try:
            write_playback_html(tmp / "trajectory.json", tmp / "playback.html", config=args.config)
        except Exception as err:  # the playback is a convenience: never lose the trajectory over it
            say(f"warning: could not write the HTML playback: {err}")
