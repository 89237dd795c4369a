"""The front door of ``pe-drake optimize``: :func:`optimize_motion`, from a resolved config to a
:class:`MotionPlan` that writes itself.

The steps: capsules fitted when the robot has none, the robot built once, a nominal posture
that clears the floor, the problem with the prior motions' data as C0 (Eq. 41), the
constraints, the multi-start solve, the ramps from and to rest, the quality figures, the
controller goal and the hardware checks.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import os
import shutil
import tempfile
import time
import weakref
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from pe_drake.config import Config, validate_config
from pe_drake.config_sections import noise_vector
from pe_drake.exceptions import ConfigError, NotWithinLimitsError, OutputWriteError, check_joints
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.constraints.base import SampledConstraint
from pe_drake.excitation.controller_goal import GoalOptions, goal_yaml_text, write_goal_bag
from pe_drake.excitation.fourier import FourierBasis, sample_times
from pe_drake.excitation.multistart import MultiStartOptions, MultiStartResult, solve_multistart
from pe_drake.excitation.nominal import choose_nominal_posture
from pe_drake.excitation.optimize_report import MotionReport, assumed_defaults, start_records
from pe_drake.excitation.parallel import Executor, ExecutorOptions, default_workers, open_executor
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.quality import RANDOM_MOTIONS, QualityReport, excitation_quality
from pe_drake.excitation.ramp import (
    RAMP_DURATIONS,
    RampedMotion,
    check_within_limits,
    check_written_motion,
    choose_ramp_duration,
)
from pe_drake.excitation.trajectory_file import (
    environment_record,
    load_motion,
    load_trajectory,
    save_trajectory,
    write_motion_csv,
)
from pe_drake.io_utils import describe_write_error, portable_config, staged_output_dir
from pe_drake.multibody.capsule_fitting import FittedCapsules, fit_capsules, with_file_margin
from pe_drake.multibody.registry import robot_display_name
from pe_drake.multibody.robot import Robot
from pe_drake.output_paths import OPTIMIZE_OUTPUTS, check_output_dir
from pe_drake.plots import plot_trajectory

Say = Callable[[str], None]
#: trajectory.csv's default rate [Hz] (``--csv-rate``): the written motion is checked at it.
DEFAULT_CSV_RATE = 1000.0


@dataclasses.dataclass(frozen=True, eq=False)
class MotionPlan:
    """An optimized exciting motion and everything ``pe-drake optimize`` writes about it.

    Attributes:
        config: the resolved config (fitted capsules, chosen nominal posture included).
        problem: the :class:`~pe_drake.excitation.problem.ExcitationProblem` (C0 included).
        constraints: the sampled constraints beyond the joint limits.
        multistart: every start and the best (``multistart.best``, an ExcitationResult).
        motion: ramp-in + periods + ramp-out (None: no valid solution).
        quality: what the motion will tell (None: no valid solution).
        goal_yaml: the FollowJointTrajectory goal's text (None: none, e.g. without ramps).
        fitted: the capsules fitted to the meshes (or None), ``fitted_text`` the file's text.
    """

    robot: Robot
    config: Config
    problem: ExcitationProblem
    constraints: tuple[SampledConstraint, ...]
    multistart: MultiStartResult
    motion: RampedMotion | None
    quality: QualityReport | None
    goal_yaml: str | None
    fitted: FittedCapsules | None
    fitted_text: str
    report: MotionReport

    @property
    def result(self):
        """The best start's :class:`~pe_drake.excitation.solve.ExcitationResult`."""
        return self.multistart.best

    @property
    def trajectory(self):
        return self.multistart.best.trajectory

    @property
    def success(self) -> bool:
        """A valid motion was found (it may still be refused for hardware: :attr:`refusal`)."""
        return bool(self.multistart.best.success)

    @property
    def refusal(self) -> str | None:
        """Why the motion must not go to hardware (a jerk limit, unchecked collisions), or None."""
        return self.report.not_valid_for_hardware

    def summary_lines(self) -> list[str]:
        """The solve's outcome, the motion's expected quality and why it must not go to hardware."""
        lines = [_outcome_line(self.multistart)]
        lines += self.quality.summary_lines() if self.quality is not None else []
        return lines + ([f"not valid for hardware: {self.refusal}"] if self.refusal is not None else [])

    def write(self, folder: str | Path, *, csv_rate: float = DEFAULT_CSV_RATE,
              playback: Callable[[MotionPlan, Path], None] | None = None, progress: Say | None = None) -> list[str]:
        """Writes trajectory.json/.csv/.png, the controller goal, the fitted capsules and
        report.json (last) into ``folder``, all or nothing (earlier runs' files of these names
        are removed); returns the paths written, sorted by name.

        Args:
            csv_rate: rate of trajectory.csv [Hz].
            playback: ``f(plan, html_path)`` writing the Meshcat playback
                (:func:`~pe_drake.viewer.write_plan_playback`); a failure there is a warning,
                sent to ``progress``.
        """
        say = progress or (lambda _line: None)
        out = check_output_dir(folder)
        check_csv_size(self.config, csv_rate)
        if self.success and self.motion is not None and csv_rate != DEFAULT_CSV_RATE:
            check_written_motion(self.motion, self.robot.limits, self.robot.joint_names, csv_rate)  # as optimize did at 1 kHz
        try:
            return self._write(out, csv_rate, playback, say)
        except OSError as err:  # a full disk: the solve must not be lost to it
            raise self._rescue(out, err) from err

    def _write(self, out: Path, csv_rate: float, playback, say: Say) -> list[str]:
        with staged_output_dir(out, "report.json", OPTIMIZE_OUTPUTS) as tmp:
            if self.success and self.refusal is None:
                self._write_motion(tmp, csv_rate)
                if playback is not None:
                    try:
                        playback(self, tmp / "playback.html")
                    except Exception as err:  # the playback is a convenience: never lose the trajectory over it
                        say(f"warning: could not write the HTML playback: {err}")
                if self.goal_yaml is not None:
                    (tmp / "trajectory_goal.yaml").write_text(self.goal_yaml)
                    write_goal_bag(tmp / "trajectory_goal_bag", self.motion, self.robot.joint_names,
                                   GoalOptions.from_config(self.config))
            report = self.report
            if self.fitted is not None:
                (tmp / self.fitted.path.name).write_text(self.fitted_text)
                report = dataclasses.replace(report, fitted_capsules=str(out / self.fitted.path.name))
            # Paths relative to the folder: a shared report names no user or folder of the author's
            (tmp / "report.json").write_text(json.dumps(portable_config(report.to_dict(), out), indent=2, default=float))
            written = sorted(p.name for p in tmp.iterdir())
        return [str(out / name) for name in written]

    def _rescue(self, out: Path, err: OSError) -> OutputWriteError:
        """Saves the solved trajectory alone (a few kB) beside ``out``'s outputs, or in the
        temporary folder when even that fails, and says where."""
        what = f"could not write the outputs into '{out}': {describe_write_error(err)}; nothing was half-written"
        if not self.success:
            return OutputWriteError(what)
        result = self.result
        for folder in (out, Path(tempfile.gettempdir())):
            path = folder / f"trajectory.rescued-{os.getpid()}.json"
            try:
                save_trajectory(path, self.robot, result.trajectory, cond=result.cond,
                                cond_motion=result.cond_motion, **self.motion.to_dict())
            except OSError:
                continue
            return OutputWriteError(f"{what}. The solved motion (cond {result.cond:.4g}) is kept in '{path}': "
                                    "pe-drake view and simulate read it; re-run optimize with the same "
                                    "seed to write the full set", rescued=str(path))
        return OutputWriteError(f"{what}, and the solved motion could not be saved anywhere either")

    def _write_motion(self, tmp: Path, csv_rate: float) -> None:
        result, robot = self.result, self.robot
        # The capsules and obstacles the run checked, so that `pe-drake view` draws them.
        capsules = self.fitted.path.name if self.fitted is not None else (self.config.robot.capsules or None)
        save_trajectory(tmp / "trajectory.json", robot, result.trajectory, cond=result.cond,
                        cond_motion=result.cond_motion, **self.motion.to_dict(), capsules=capsules,
                        environment=environment_record(self.config.environment))
        write_motion_csv(tmp / "trajectory.csv", robot.joint_names, self.motion, csv_rate)
        plot_trajectory(tmp / "trajectory.png", robot, result.trajectory, result.singular_values,
                        title=f"{robot.name}: cond {result.cond:.4g}",
                        note=self.quality.figure_note() if self.quality is not None else "")


def check_csv_size(config: Config, rate: float, max_rows: int = 10_000_000) -> None:
    """Refuses (ConfigError) a trajectory.csv too large to write (periods × period × rate)."""
    if not (math.isfinite(rate) and 1.0 <= rate <= 10_000.0):
        raise ConfigError(f"--csv-rate must be from 1 to 10000 Hz, got {rate:g}")
    e = config.excitation
    duration = e.periods * 2 * math.pi / e.omega + (2 * max(RAMP_DURATIONS) if e.ramp else 0.0)
    if duration * rate > max_rows:
        raise ConfigError(
            f"trajectory.csv would hold up to {duration * rate:.3g} rows ({e.periods} period(s) of "
            f"{2 * math.pi / e.omega:.4g} s at {rate:g} Hz); use fewer --periods or a lower --csv-rate "
            f"(at most {max_rows:.0e} rows)"
        )


def optimize_motion(config: Config, *, priors: Sequence[str | Path] = (),
                    executor: Executor | None = None, progress: Say | None = None,
                    name: str | None = None, allow_unchecked: bool = False) -> MotionPlan:
    """Optimizes an exciting motion: everything ``pe-drake optimize`` does (module docstring).

    Args:
        config: the resolved :class:`~pe_drake.config.Config` (e.g.
            :func:`~pe_drake.multibody.registry.resolve_robot_config`); it is not changed.
        priors: earlier ``trajectory.json`` files whose data is reused as C0 (Eq. 41).
        executor: an open executor to solve the starts on (its robot is used); default: one
            opened from ``config.parallel`` for this call.
        progress: called with one line per step.
        name: the robot's name (default: its built-in name or model file's stem).
        allow_unchecked: a robot with parts that could not be checked for collision is still
            valid for hardware (they stay listed in the report).

    Raises:
        ConfigError, DataError, NotWithinLimitsError, InfeasibleError: bad settings, prior
            files or a robot that cannot be built; WorkerError: a start failed in a worker.
    """
    start = time.perf_counter()
    say = progress or (lambda _line: None)
    config = validate_config(copy.deepcopy(config))  # the caller's config is never changed
    for prior in priors:
        load_motion(prior)  # every value of each file, ramps included: before any work
    fit_dir = Path(tempfile.mkdtemp(prefix="pe_drake_capsules_"))  # lives as long as the plan (its config names it)
    try:
        config, fitted, unchecked = collision_geometry(config, fit_dir, say)
        fitted_text = fitted.path.read_text() if fitted is not None else ""
        if executor is not None:
            plan = _plan(config, executor.local.robot, executor, priors, fitted, fitted_text, unchecked, allow_unchecked,
                         start, say)
        else:
            robot = _robot(config, name or robot_display_name(config.robot.model), say)
            noise_vector(config.excitation.noise_std.torque, robot.joint_names)  # a bad noise_std: before solving
            par = config.parallel
            # A shared config's 'workers: 200' would start 200 Drake processes on this machine.
            workers = min(par.workers, default_workers()) if par.executor == "local" and par.workers else par.workers
            with open_executor(robot, par.executor, workers or None, tasks=par.starts, address=par.address,
                               measurement=config.excitation.measurement, hung_after_s=par.hung_after_s,
                               constraints_factory=functools.partial(
                                   constraints_from_config, environment=config.environment)) as own:
                plan = _plan(config, robot, own, priors, fitted, fitted_text, unchecked, allow_unchecked, start, say)
    except BaseException:
        shutil.rmtree(fit_dir, ignore_errors=True)
        raise
    weakref.finalize(plan, shutil.rmtree, fit_dir, True)
    return plan


def collision_geometry(config: Config, fit_dir: Path, say: Say) -> tuple[Config, FittedCapsules | None, list[str]]:
    """The config with fitted capsules when the robot has none, and what stays unchecked."""
    margin_before = config.excitation.collision_margin
    config = with_file_margin(config)  # a capsule file passed back keeps the margin it was fitted with
    try:
        config, fitted = fit_capsules(config, fit_dir)
    except ConfigError as err:
        if config.excitation.collision_margin >= 0 or config.environment.boxes:
            raise
        # Only a missing collision geometry turns the floor off: a robot that does not load at
        # all is refused by its own error (issue 37).
        Robot(robot_display_name(config.robot.model), config.robot)
        say(f"warning: {err}; the floor is NOT checked (environment.floor turned off)")
        config = dataclasses.replace(config, environment=dataclasses.replace(config.environment, floor=False))
        return config, None, [f"floor: no collision geometry to check it with ({err})"] + list(getattr(err, "unchecked", ()))
    if fitted is None and config.excitation.collision_margin != margin_before:
        say(f"self-collision margin {config.excitation.collision_margin:g} m: the capsule file's collision_margin "
            f"({config.robot.capsules}; set excitation.collision_margin to change it)")
    if fitted is not None:
        say(f"no capsule file: fitted capsules: {fitted.summary()}; self-collision margin "
            f"{config.excitation.collision_margin:g} m"
            + (f"; {fitted.pairs_summary()}" if fitted.pairs_summary() else ""))
    return config, fitted, list(fitted.unchecked) if fitted is not None else []


def _robot(config: Config, name: str, say: Say) -> Robot:
    """The robot, built once, with its notes and a nominal posture that clears the floor."""
    robot = Robot(name, config.robot)
    say(f"robot {robot.name}: {robot.n} excited joints, {robot.num_bodies} moving bodies")
    for note in assumed_defaults(config, robot.joint_names, [j.kind for j in robot.joints]) + list(robot.notes) + list(robot.limit_notes):
        say(f"note: {note}")  # assumed limits; what the model needed for Drake (mimic, materials, mount)
    nominal = choose_nominal_posture(robot, config.excitation, config.environment)
    if nominal is not None:
        say(f"note: {nominal}")
    return robot


def prior_regressor(problem: ExcitationProblem, trajectory_json: str | Path) -> np.ndarray:
    """Stacked rows of C of an earlier motion (for C0, Eq. 41), at the problem's number of cost
    samples over that motion's own period; DataError if the file's joints differ."""
    trajectory, data = load_trajectory(trajectory_json)
    joints = tuple(data["joints"])
    check_joints(problem.robot, joints, file=str(trajectory_json), what="the prior motion")
    check_within_limits(RampedMotion(trajectory), problem.robot.limits, joints, source=str(trajectory_json))
    basis = FourierBasis(trajectory.harmonics, trajectory.omega, sample_times(trajectory.period, problem.config.cost_samples))
    a, b = trajectory.a, trajectory.b
    return problem.rows_at(basis.q(a, b, trajectory.q0), basis.v(a, b), basis.vd(a, b))  # torques, wrench or both


def _plan(config, robot: Robot, executor, priors, fitted, fitted_text, unchecked, allow_unchecked, start, say) -> MotionPlan:
    e = config.excitation
    problem = executor.problem(e)
    if priors:
        problem = executor.problem(e, np.vstack([prior_regressor(problem, p) for p in priors]))
        say(f"prior data: {len(priors)} motion(s), {problem.C0.shape[0]} rows, cond(C0) = {np.linalg.cond(problem.C0):.4g}")
    drive = f" and {problem.drive.count} drive terms ({e.drive_terms})" if problem.drive.count else ""
    say(f"{problem.base.count} base parameters of the {e.measurement} rows{drive}; {problem.num_variables} variables "
        f"(N = {problem.harmonics}, ω = {problem.omega:.4g} rad/s, period {problem.period:.3g} s); "
        f"T = {e.cost_samples} cost samples, K = {e.constraint_samples} constraint samples")
    if problem.base.rank_note:
        say(f"note: {problem.base.rank_note}")
    constraints = tuple(executor.local.constraints(e))
    if constraints:
        say("constraints: joint limits, " + ", ".join(c.name for c in constraints))
    ms = _solve_starts(problem, executor, config, say)
    result = ms.best
    say(_outcome_line(ms))
    say("minimum margins at 1 kHz: " + ", ".join(f"{k} {m:.4g}" for k, m in result.margins.items()))
    motion = quality = goal = refusal = ramp_margins = None
    if result.success:
        motion, ramp_margins = _ramped_motion(result, robot, constraints, config, say)
        # A few seconds with collision and balance: say what runs (the solve's output has ended).
        say(f"expected quality: the motion and {RANDOM_MOTIONS} random motions under the same constraints ...")
        quality = excitation_quality(problem, result.x, constraints, noise_std=e.noise_std.torque, periods=int(e.periods))
        for line in quality.summary_lines():
            say(line)
        goal, refusal = _controller_goal(motion, robot, config, say)
        refusal = _outside_limits(motion, robot) or refusal
    if unchecked:
        say(f"NOT checked ({len(unchecked)}): " + "; ".join(unchecked[:5]) + (" ..." if len(unchecked) > 5 else ""))
        if refusal is None and not allow_unchecked:
            refusal = (f"{len(unchecked)} part(s) of the robot were not checked for collision (listed in "
                       "report.json 'unchecked'); give robot.capsules, or --allow-unchecked to write it anyway")
    report = MotionReport(
        robot=robot.name, success=result.success, converged=result.converged, message=result.message, status=result.status, solver=result.solver,
        criterion=e.criterion, measurement=e.measurement, cond=result.cond, cond_motion=result.cond_motion,
        criterion_value=result.fun, iterations=result.nit, evaluations=result.nfev, seed=ms.seed,
        solve_time_s=result.wall_time, multistart_time_s=ms.wall_time, total_time_s=time.perf_counter() - start,
        executor={"name": ms.executor, "workers": ms.workers, "address": config.parallel.address},
        starts=start_records(ms), margins_1khz=result.margins, base_parameters=problem.base.count,
        base_parameter_names=list(problem.base.base_names), singular_values=result.singular_values.tolist(),
        prior=[str(p) for p in priors], config=dataclasses.asdict(config),
        assumed_defaults=assumed_defaults(config, robot.joint_names, [j.kind for j in robot.joints]), fitted_capsules=None,
        ignored_pairs=fitted.ignored_records() if fitted is not None else [],
        shrunk_capsules={n: {"fitted_radius": a, "radius": b} for n, (a, b) in fitted.shrunk.items()} if fitted is not None else {},
        limit_margins=limit_margins(config), ramp_margins_1khz=ramp_margins,
        motion=motion.to_dict() if motion is not None else None,
        quality=quality.to_dict() if quality is not None else None, unchecked=list(unchecked),
        not_valid_for_hardware=refusal,
    )
    return MotionPlan(robot=robot, config=config, problem=problem, constraints=constraints, multistart=ms, motion=motion,
                      quality=quality, goal_yaml=goal, fitted=fitted, fitted_text=fitted_text, report=report)


def _outcome_line(ms: MultiStartResult) -> str:
    r = ms.best
    return (f"{'valid' if r.success else 'FAILED'}: {r.message}; cond {r.cond:.5g} (this motion alone "
            f"{r.cond_motion:.5g}), seed {ms.seed}, {r.nit if r.nit is not None else '-'} iterations, "
            f"{r.nfev} evaluations, {r.wall_time:.1f} s")


def _solve_starts(problem: ExcitationProblem, executor: Executor, config: Config, say: Say) -> MultiStartResult:
    """Multi-start (start k: seed + k) on the executor; the best feasible start is kept."""
    par = config.parallel
    seeds = [config.excitation.seed + k for k in range(par.starts)]
    where = "in this process" if executor.name == "main" else f"on {executor.workers} {executor.name} worker(s)"
    say(f"solving {par.starts} start(s) (seeds {seeds[0]}..{seeds[-1]}) {where} with {config.solver.name} "
        f"(max {config.solver.max_iterations} iterations) ...")

    def progress(event) -> None:
        if event.kind != "progress" or config.solver.verbose:
            say(str(event))

    options = MultiStartOptions(seeds, C0=problem.C0, run=ExecutorOptions(executor=executor))
    return solve_multistart(None, config.excitation, config.solver, options, progress=progress)


def _ramped_motion(result, robot: Robot, constraints, config: Config, say: Say) -> RampedMotion:
    """The controller motion: ramp-in + N periods + ramp-out (or N periods without ramps)."""
    periods = config.excitation.periods
    if not config.excitation.ramp:
        say(f"ramps off (excitation.ramp: false): trajectory.csv is {periods} period(s) and does NOT start at rest")
        return RampedMotion(result.trajectory, periods, 0.0), None
    say("choosing ramps from and to rest (each candidate checked at 1 kHz against every limit and constraint) ...")
    motion, checks = choose_ramp_duration(result.trajectory, robot.limits, constraints, periods=periods)
    say(f"ramps from and to rest: {motion.ramp_duration:g} s each (join phase {motion.phase:.3g} s), "
        f"{periods} period(s); trajectory.csv spans {motion.duration:.4g} s, the periodic part "
        f"[{motion.periodic_start:.4g}, {motion.periodic_end:.4g}] s; ramp margins at 1 kHz: "
        + ", ".join(f"{k} {m:.4g}" for k, m in checks[-1].margins.items()))
    return motion, dict(checks[-1].margins)


def _outside_limits(motion: RampedMotion, robot: Robot, rate: float = DEFAULT_CSV_RATE) -> str | None:
    """Why the motion written at ``rate`` leaves a joint limit (by any amount), or None: the
    final check of what trajectory.csv holds, ramps and periods included."""
    try:
        check_written_motion(motion, robot.limits, robot.joint_names, rate)
    except NotWithinLimitsError as err:
        return f"the written motion leaves a joint limit: {err}"
    return None


def limit_margins(config: Config) -> dict:
    """The margins the limits were used with (report.json ``limit_margins``), and which of
    them pe_drake assumed for a model given without a config (``assumed``)."""
    r = config.robot
    return {"position_margin": r.position_margin, "position_margin_unit": "rad (m for prismatic joints)",
            "velocity_scale": r.velocity_scale, "acceleration_scale": r.acceleration_scale,
            "effort_scale": r.effort_scale, "assumed": list(r.assumed)}


def _controller_goal(motion: RampedMotion, robot: Robot, config: Config, say: Say) -> tuple[str | None, str | None]:
    """(trajectory_goal.yaml's text or None, the reason the motion is refused or None).

    A motion without ramps does not start at rest and gets no goal. A jerk above
    ``robot.jerk_limits`` refuses the whole motion: the CSV would carry the same jerk.
    """
    if motion.ramp_duration <= 0:
        say("no trajectory_goal.yaml: the motion has no ramps, so it does not start at rest")
        return None, None
    try:
        return goal_yaml_text(motion, robot.joint_names, GoalOptions.from_config(config)), None
    except NotWithinLimitsError as err:
        return None, str(err)
