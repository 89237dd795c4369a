"""Solving a built excitation program with IPOPT or NLopt, and checking the result at 1 kHz.

:func:`solve_excitation` runs the solver, re-checks every constraint between the samples (adding
violated instants and solving again: :mod:`pe_drake.excitation.exchange`), falls back to the best
feasible point evaluated when the solver stops at an infeasible iterate, and reports it all in an
:class:`ExcitationResult`. :func:`optimize_excitation` builds and solves in one call.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from pe_drake.config import Config, ExcitationConfig, SolverConfig, validate_config
from pe_drake.exceptions import ConfigError, NoSolutionFound
from pe_drake.excitation.constraints.base import SampledConstraint, state_margins
from pe_drake.excitation.exchange import add_violated_samples
from pe_drake.excitation.fourier import FourierBasis, FourierTrajectory
from pe_drake.excitation.limits import keep_strictly_inside
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import ExcitationProgram, build_excitation_program
from pe_drake.excitation.scaling import solve_scaled
from pe_drake.excitation.solver_logs import new_log_file
from pe_drake.excitation.stall import CriterionStalled, StalledResult, stall_rule_active
from pe_drake.memory import reuse_freed_memory
from pe_drake.threads import single_threaded_blas

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Quasi-Newton pairs IPOPT keeps (its default is 6), in alpha and in the harmonic coordinates
#: of :mod:`pe_drake.excitation.scaling` (measurements: BUILD_NOTES.md).
LBFGS_PAIRS, SCALED_LBFGS_PAIRS = 30, 12


def option_value(text: str) -> int | float | str:
    """An IPOPT option written as text as an int, a float or a word (IPOPT's options are typed)."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


@dataclasses.dataclass
class ExcitationResult:
    """Outcome of :func:`solve_excitation`.

    Attributes:
        x: optimal alpha, shape ((2N+1)·n,); ``fun`` the criterion there.
        cond: cond(C) at x (C includes C0).
        cond_motion: cond of this motion's own Ŷ_B.
        success: x is a valid trajectory: every constraint holds at 1 kHz (after an early stop
            at an infeasible iterate, x is the best feasible point evaluated, if any).
        message: solver status, which constraint fails by how much, or the fallback used.
        status: Drake's solution result name, or "kStalled" (:mod:`pe_drake.excitation.stall`).
        nit: solver iterations (IPOPT: from its log; NLopt: None).
        wall_time: [s].
        margins: {constraint: minimum margin at 1 kHz} (negative = violated), in the
            constraint's units (rad, rad/s, rad/s², m, N·m).
        solves: solver runs (1 + the exchange step's re-solves); ``nit`` sums them.
        exchange_samples: instants the exchange step added to the program.
        far_from_convergence: see :func:`far_from_convergence`; not a result, so ``success``
            is False whatever the 1 kHz re-check says.
    """

    x: np.ndarray
    trajectory: FourierTrajectory
    fun: float
    cond: float
    cond_motion: float
    success: bool
    converged: bool
    message: str
    status: str
    nit: int | None
    nfev: int
    wall_time: float
    margins: dict[str, float]
    singular_values: np.ndarray
    solver: str
    raw: object = None
    solves: int = 1
    exchange_samples: int = 0
    far_from_convergence: bool = False


def check_margins(
    problem: ExcitationProblem, alpha: np.ndarray, constraints: list[SampledConstraint] = (), rate: float = 1000.0
) -> dict[str, float]:
    """Minimum margin of each constraint over one period sampled at ``rate`` [Hz] (negative is
    violated); joint limits per quantity (``position``, ``velocity``, ``acceleration``)."""
    t = np.arange(0.0, problem.period, 1.0 / rate)
    basis = FourierBasis(problem.harmonics, problem.omega, t)
    return state_margins(problem.robot.limits, constraints, *basis.evaluate_alpha(np.asarray(alpha, float), problem.n))


class _IterationLimitWarningFilter(logging.Filter):
    """Drops Drake's warning on every IPOPT run that stops at ``max_iter``: its hint about
    unbounded variables does not apply (the joint-limit rows bound alpha), and
    :func:`solve_excitation` reports the iteration limit itself."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not record.getMessage().startswith("IPOPT terminated after exceeding the maximum iteration limit")


def _quiet_iteration_limit_warning() -> None:
    drake_logger = logging.getLogger("drake")
    if not any(isinstance(f, _IterationLimitWarningFilter) for f in drake_logger.filters):
        drake_logger.addFilter(_IterationLimitWarningFilter())


class _Backend(NamedTuple):
    """A Drake solver with its options for one solve."""

    solver: object  # IpoptSolver or NloptSolver
    options: object  # SolverOptions
    log_file: Path | None  # IPOPT's log, read for the iteration count


def _ipopt_backend(cfg: SolverConfig) -> _Backend:
    # pydrake is imported lazily so that `import pe_drake` stays light.
    from pydrake.solvers import CommonSolverOption, IpoptSolver, SolverOptions

    _quiet_iteration_limit_warning()
    solver, options = IpoptSolver(), SolverOptions()
    sid = solver.solver_id()
    options.SetOption(sid, "max_iter", int(cfg.max_iterations))
    options.SetOption(sid, "tol", float(cfg.tolerance))
    options.SetOption(sid, "acceptable_tol", float(cfg.tolerance) * 100)
    options.SetOption(sid, "print_level", 0)
    options.SetOption(sid, "file_print_level", 5)
    options.SetOption(sid, "hessian_approximation", "limited-memory")
    # Each option below was measured on G1 and the Panda (BUILD_NOTES.md). SPRAL's default
    # scaling redoes the symbolic analysis at every factorization.
    options.SetOption(sid, "spral_scaling", "none")
    options.SetOption(sid, "limited_memory_max_history", LBFGS_PAIRS)
    # The quasi-Newton pairs as extra rows of the augmented system: the same steps, without
    # Sherman-Morrison's two back-solves per pair after every factorization.
    options.SetOption(sid, "limited_memory_aug_solver", "extended")
    # Our KKT systems are a few hundred dense columns and thousands of nearly empty rows:
    # amalgamating fewer supernodes than SPRAL's default 32 halves the factorization time.
    options.SetOption(sid, "spral_nemin", 4)
    # No second-order corrections: each costs a constraint evaluation and rarely rescued a step.
    options.SetOption(sid, "max_soc", 0)
    for key, value in cfg.ipopt_options.items():  # the config's own, last (data, not a global)
        options.SetOption(sid, key, option_value(str(value)))
    if cfg.max_time > 0:
        options.SetOption(sid, "max_wall_time", float(cfg.max_time))
    # IPOPT reports no iteration count through Drake: its log file does (solver_logs.py).
    log_file = new_log_file()
    options.SetOption(CommonSolverOption.kPrintFileName, str(log_file))
    return _Backend(solver, options, log_file)


def _nlopt_backend(cfg: SolverConfig) -> _Backend:
    from pydrake.solvers import NloptSolver, SolverOptions  # lazily, as above

    solver, options = NloptSolver(), SolverOptions()
    sid = solver.solver_id()
    options.SetOption(sid, "algorithm", cfg.algorithm)
    options.SetOption(sid, "max_eval", int(cfg.max_iterations))
    options.SetOption(sid, "xtol_rel", float(cfg.tolerance))
    options.SetOption(sid, "constraint_tol", 1e-6)
    if cfg.max_time > 0:
        options.SetOption(sid, "max_time", float(cfg.max_time))
    return _Backend(solver, options, None)


def _backend(cfg: SolverConfig) -> _Backend:
    """The Drake solver named by ``cfg`` (validated) with its options, refused if Drake lacks it."""
    backend = _ipopt_backend(cfg) if cfg.name == "ipopt" else _nlopt_backend(cfg)
    if not backend.solver.available() or not backend.solver.enabled():
        raise ConfigError(f"solver '{cfg.name}' is not available in this Drake build")
    return backend


def _run_solver(program: ExcitationProgram, solver, x0: np.ndarray, options):
    """One Drake solve of the program from x0, in the coordinates of ``program.variable_scale``."""
    try:
        if program.variable_scale is None:
            return solver.Solve(program.prog, x0, options)
        return solve_scaled(
            solver, program.prog, program.alpha, program.variable_scale, x0, options, program.own_evaluators()
        )
    except CriterionStalled as stop:
        best = program.cost.candidates
        return StalledResult(program.alpha, best[0][1] if best else np.asarray(x0, float), str(stop))


def _solve_with_restarts(program: ExcitationProgram, backend: _Backend, cfg: SolverConfig, x0: np.ndarray):
    """Runs the solver from x0; returns Drake's result and a note on any restart ("" if none)."""
    problem = program.problem
    result = _run_solver(program, backend.solver, x0, backend.options)
    stalled = ""
    if cfg.name == "nlopt" and cfg.algorithm == "LD_SLSQP" and problem.num_evaluations <= 2:
        # SLSQP sometimes stops after one evaluation with XTOL_REACHED (a zero first QP step):
        # not an optimum. Retry from the motion shrunk by 5 % toward its offsets (still within
        # the limits, which are linear in alpha), then with MMA (robust, slow).
        retry = x0.copy()
        retry[: -problem.n] *= 0.95
        result = _run_solver(program, backend.solver, retry, backend.options)
        stalled = "; LD_SLSQP stalled at the start, restarted from the motion shrunk by 5 %"
        if problem.num_evaluations <= 4:
            backend.options.SetOption(backend.solver.solver_id(), "algorithm", "LD_MMA")
            result = _run_solver(program, backend.solver, x0, backend.options)
            stalled = "; LD_SLSQP stalled twice at the start, solved with LD_MMA"
    return result, stalled


def _iterations_from_log(log_file: Path | None) -> int | None:
    """IPOPT's iteration count from its log (which is then deleted); None without a log."""
    if log_file is None:
        return None
    text = log_file.read_text(errors="replace") if log_file.exists() else ""
    m = re.search(r"Number of Iterations\.*:\s*(\d+)", text)
    log_file.unlink(missing_ok=True)
    if m:
        return int(m.group(1))
    # A solve ended by the stall rule writes no summary: its last iteration line counts.
    rows = re.findall(r"^\s*(\d+)r?\s+[-+]?\d\.\d+e[-+]\d+\s", text, flags=re.M)
    return int(rows[-1]) if rows else None


#: The margins of :func:`check_margins` that are joint limits (below 0 is a violation).
JOINT_LIMIT_KEYS = ("position", "velocity", "acceleration")


class _Check(NamedTuple):
    """How the solution is re-checked between the samples."""

    rate: float  # [Hz]
    tolerance: float  # a margin below -tolerance is a violation, in the constraint's units


class _Run(NamedTuple):
    """The solver runs of one solve."""

    result: object  # Drake's result of the last run
    note: str  # restarts and exchange steps, for the message ("" if none)
    nit: int | None  # iterations summed over the runs (IPOPT), None for NLopt
    solves: int
    added: int  # instants added by the exchange step


#: Share of the iteration budget the first IPOPT run may use; the rest is kept for the
#: exchange step's re-solves (the first run mostly stops at its iteration limit).
FIRST_SOLVE_SHARE = 0.9


def _solve_with_exchange(program, backend: _Backend, cfg: SolverConfig, x0: np.ndarray, check: _Check) -> _Run:
    """Solves, then, while the budget of ``cfg.max_iterations`` IPOPT iterations lasts, adds
    the instants violated at ``check.rate`` (:mod:`~pe_drake.excitation.exchange`) and solves
    again from the last point (an unconverged run is continued too)."""
    if cfg.name == "ipopt":
        first = max(1, int(FIRST_SOLVE_SHARE * cfg.max_iterations))
        backend.options.SetOption(backend.solver.solver_id(), "max_iter", first)
    result, note = _solve_with_restarts(program, backend, cfg, x0)
    nit = _iterations_from_log(backend.log_file)
    solves, added = 1, 0
    while cfg.name == "ipopt" and nit is not None and nit < cfg.max_iterations:
        x = np.asarray(result.GetSolution(program.alpha), float)
        new = add_violated_samples(program, x, check.rate, check.tolerance)
        if not new and (result.is_success() or isinstance(result, StalledResult)):
            break
        added += new
        program.cost.best_history.clear()  # a re-solve gets the stall rule's full allowance
        rerun = _ipopt_backend(dataclasses.replace(cfg, max_iterations=cfg.max_iterations - nit))
        result = _run_solver(program, rerun.solver, x, rerun.options)
        ran = _iterations_from_log(rerun.log_file) or 0
        nit += ran
        solves += 1
        if ran == 0:  # IPOPT stopped at once (e.g. its time limit): no progress to wait for
            break
    if added:
        note += f"; exchange: {added} instant(s) added, {solves} solves"
    return _Run(result, note, nit, solves, added)


def shrink_into_limits(problem: ExcitationProblem, alpha: np.ndarray, rate: float = 1000.0) -> np.ndarray:
    """alpha with its motion about the offsets q0 scaled by the largest s ≤ 1 that keeps q, v
    and vdot within the joint limits at ``rate`` [Hz] (they are linear in the motion)."""
    alpha = np.asarray(alpha, float)
    t = np.arange(0.0, problem.period, 1.0 / rate)
    q, v, vd = FourierBasis(problem.harmonics, problem.omega, t).evaluate_alpha(alpha, problem.n)
    lim, q0 = problem.robot.limits, alpha[-problem.n :]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.concatenate([
            np.where(q.max(0) > q0, (lim.q_upper - q0) / (q.max(0) - q0), np.inf),
            np.where(q.min(0) < q0, (q0 - lim.q_lower) / (q0 - q.min(0)), np.inf),
            lim.v_max / np.abs(v).max(0),
            lim.vd_max / np.abs(vd).max(0),
        ])
    scale = min(1.0, float(np.min(ratios)) * (1 - 1e-9))
    out = alpha * scale
    out[-problem.n :] = q0
    return out


#: Shares of the way :func:`blend_toward_start` tries, in order.
BLEND_SHARES = (0.001, 0.01, 0.05, 0.1, 0.25, 0.5, 0.75)


def blend_toward_start(
    program: ExcitationProgram, start: np.ndarray, target: np.ndarray, rate: float = 1000.0, tolerance: float = 1e-6
):
    """(share, point, margins) of the first ``target + share·(start − target)``, for the
    shares of :data:`BLEND_SHARES`, that holds every constraint at ``rate`` [Hz] (margins ≥
    −``tolerance``), or None when none does or the start itself does not.

    The last resort of :func:`solve_excitation` when every point evaluated crosses a sampled
    constraint between the samples by a little: the joint limits and rest hold on the whole
    segment (linear in alpha), and a point closer to the valid start usually clears the rest."""
    problem, constraints = program.problem, program.constraints
    if min(check_margins(problem, start, constraints, rate=rate).values()) < -tolerance:
        return None
    for share in BLEND_SHARES:
        point = target + share * (start - target)
        margins = check_margins(problem, point, constraints, rate=rate)
        if min(margins.values()) >= -tolerance:
            return share, point, margins
    return None


def _feasible_fallback(program: ExcitationProgram, x: np.ndarray, solved: bool, check: _Check, start: np.ndarray):
    """The solution, its margins at ``check.rate`` and a note on the fallback used ("" if none).

    An infeasible or unconverged iterate is replaced by the lower-valued valid one of: the
    iterate shrunk into the joint limits (:func:`shrink_into_limits`), the best points evaluated;
    else by the best point (or the iterate) moved toward the valid ``start``
    (:func:`blend_toward_start`).
    """
    problem = program.problem
    margins = check_margins(problem, x, program.constraints, rate=check.rate)
    if solved and min(margins.values()) >= -check.tolerance:
        return x, margins, ""
    shrunk = shrink_into_limits(problem, x, check.rate)
    m = check_margins(problem, shrunk, program.constraints, rate=check.rate)
    best = None
    if min(m.values()) >= -check.tolerance:
        value = problem.evaluate(shrunk).value
        note = f"; returned the last iterate shrunk into the joint limits ({problem.config.criterion} {value:.5g})"
        best = (value, shrunk, m, note)
    for value, candidate in program.cost.candidates:
        if (solved and value >= problem.evaluate(x).value) or (best is not None and value >= best[0]):
            break
        m = check_margins(problem, candidate, program.constraints, rate=check.rate)
        if min(m.values()) >= -check.tolerance:
            return candidate, m, f"; returned the best feasible point evaluated ({problem.config.criterion} {value:.5g})"
    if best is not None:
        return best[1:]
    candidates = program.cost.candidates
    target, which = (candidates[0][1], "the best one") if candidates else (x, "the last iterate")
    blend = blend_toward_start(program, start, target, check.rate, check.tolerance)
    if blend is not None:
        share, point, m = blend
        value = problem.evaluate(point).value
        note = (
            f"; no point evaluated was valid at {check.rate:g} Hz: returned {which} moved {share:.1%} "
            f"toward the start ({problem.config.criterion} {value:.5g})"
        )
        return point, m, note
    return x, margins, ""


def _message(cfg: SolverConfig, result, violated: dict[str, float], fallback: str, stalled: str) -> str:
    """What happened: the violated constraints, the solver status, the fallback, the restart."""
    status = result.get_solution_result().name
    if violated:
        message = "solution violates between samples: " + ", ".join(f"{k} by {-m:.3g}" for k, m in violated.items())
    elif not result.is_success():
        # The point is valid (re-checked at 1 kHz): say that the solver stopped, not that
        # something failed, so that "valid" and the status do not read as a contradiction.
        limit = status == "kIterationLimit"
        where = f"at its iteration limit ({cfg.max_iterations})" if limit else "early"
        where = "when the criterion stalled" if status == "kStalled" else where
        detail = f": {result.get_solver_details().ConvertStatusToString()}" if cfg.name == "ipopt" else ""
        message = f"{cfg.name} stopped {where} before converging ({status}{detail})" + fallback
        if limit:  # the budget, not convergence, ended the solve (issue 37)
            message += ("; more iterations (solver.max_iterations, --max-iterations) may still lower the criterion, "
                        "at about the same time per iteration")
    else:  # converged, yet its point may have failed the re-check and been replaced
        message = f"{cfg.name}: {status}" + fallback
    return message + stalled


#: Factor of :func:`far_from_convergence` (issue 38: unconverged starts had been labelled
#: valid at many times their rivals' cond).
FAR_FROM_CONVERGENCE = 2.0


def far_from_convergence(converged: bool, value: float, best_evaluated: float | None, criterion: str = "soft_cond") -> bool:
    """Whether a solve's returned point is no result: the solver did not converge and its
    criterion ``value`` is above :data:`FAR_FROM_CONVERGENCE` times ``best_evaluated`` (the
    lowest criterion evaluated within the joint limits, or None), or not finite. For
    ``log_cond`` the factor applies to cond; ``dopt`` (any sign) is judged by finiteness only."""
    if converged:
        return False
    if not np.isfinite(value):
        return True
    if best_evaluated is None or criterion == "dopt":
        return False
    if criterion == "log_cond":
        return bool(value - best_evaluated > np.log(FAR_FROM_CONVERGENCE))
    return bool(value > FAR_FROM_CONVERGENCE * best_evaluated)


def _cond(singular_values: np.ndarray) -> float:
    return float(singular_values[0] / singular_values[-1]) if singular_values[-1] > 0 else np.inf


def solve_excitation(
    program: ExcitationProgram,
    solver: str | SolverConfig = "ipopt",
    initial_guess: np.ndarray | None = None,
    *,
    check_rate: float = 1000.0,
    tolerance: float = 1e-6,
    exchange: bool = True,
) -> ExcitationResult:
    """Solves a built excitation program with IPOPT or NLopt.

    Args:
        program: from :func:`build_excitation_program` (possibly with user additions).
        initial_guess: alpha to start from (default: ``problem.initial_guess()``).
        check_rate: rate [Hz] at which the constraints are re-checked after solving.
        tolerance: margin below −tolerance counts as a violation in the re-check.
        exchange: with IPOPT, add the instants where a sampled constraint is violated at
            ``check_rate`` and solve again, within the same total of iterations.

    Returns:
        An :class:`ExcitationResult`; ``success`` is False if the solver failed or any
        constraint is violated between the samples (``message`` says which and by how much).
    """
    cfg = solver if isinstance(solver, SolverConfig) else SolverConfig(name=solver)
    validate_config(Config(solver=cfg))
    if program.variable_scale is not None and "limited_memory_max_history" not in cfg.ipopt_options:
        pairs = {**cfg.ipopt_options, "limited_memory_max_history": SCALED_LBFGS_PAIRS}
        cfg = dataclasses.replace(cfg, ipopt_options=pairs)
    problem = program.problem
    x0 = problem.initial_guess() if initial_guess is None else np.asarray(initial_guess, float)
    if x0.shape != (problem.num_variables,):
        raise ConfigError(f"initial guess has shape {x0.shape}, expected ({problem.num_variables},)")
    backend = _backend(cfg)

    problem.num_evaluations = 0
    program.cost.reset()
    check = _Check(check_rate, tolerance)
    reuse_freed_memory()  # a third of each evaluation went to faulting in fresh pages
    start = time.perf_counter()
    # NLopt's C callbacks swallow a Python exception (DRAKE_NOTES.md): the stall rule is IPOPT's.
    with single_threaded_blas(), stall_rule_active(program.cost, cfg.name == "ipopt"):
        if exchange:
            run = _solve_with_exchange(program, backend, cfg, x0, check)
        else:
            result, note = _solve_with_restarts(program, backend, cfg, x0)
            run = _Run(result, note, _iterations_from_log(backend.log_file), 1, 0)
    wall = time.perf_counter() - start
    result = run.result

    solved = result.is_success()
    x = np.asarray(result.GetSolution(program.alpha), float)
    with single_threaded_blas():  # BLAS's threads spin on a loaded machine
        x, margins, fallback = _feasible_fallback(program, x, solved, check, x0)
        x, scale = keep_strictly_inside(problem, x)
        if scale < 1.0:
            margins = check_margins(problem, x, program.constraints, rate=check.rate)
            fallback += f"; motion scaled by 1 - {1 - scale:.2g} to keep strictly inside the joint limits"
        cost = problem.evaluate(x)
        cond_motion = _cond(np.linalg.svd(problem.regressor_block(x), compute_uv=False))
    # Nothing outside a joint limit is valid (issue 21): the tolerance is for the others only.
    violated = {k: m for k, m in margins.items() if m < (0.0 if k in JOINT_LIMIT_KEYS else -tolerance)}
    best = program.cost.best_value
    far = far_from_convergence(bool(solved), float(cost.value), best, problem.config.criterion)
    if far:
        fallback += (
            f"; FAR FROM CONVERGENCE: {problem.config.criterion} {cost.value:.5g} is more than "
            f"{FAR_FROM_CONVERGENCE:g}x the best point within the joint limits evaluated ({best:.5g}): not a result"
            if best is not None and np.isfinite(cost.value)
            else "; FAR FROM CONVERGENCE: the criterion is not finite: not a result"
        )
    return ExcitationResult(
        x=x, trajectory=problem.trajectory(x), fun=float(cost.value),
        cond=_cond(cost.singular_values), cond_motion=cond_motion, success=not violated and not far,
        converged=bool(solved), message=_message(cfg, result, violated, fallback, run.note),
        status=result.get_solution_result().name, nit=run.nit, nfev=problem.num_evaluations,
        wall_time=wall, margins=margins, singular_values=cost.singular_values, solver=cfg.name,
        raw=result, solves=run.solves,
        exchange_samples=run.added, far_from_convergence=far,
    )


def optimize_excitation(
    robot: Robot,
    config: ExcitationConfig | None = None,
    solver: str | SolverConfig = "ipopt",
    *,
    C0: np.ndarray | None = None,
    constraints: list[SampledConstraint] | None = None,
    initial_guess: np.ndarray | None = None,
    progress: bool = False,
    raise_on_failure: bool = False,
) -> ExcitationResult:
    """Builds and solves in one call (see :func:`build_excitation_program`).

    Raises:
        NoSolutionFound: with ``raise_on_failure``, when no valid trajectory was found (the
            result is kept in the exception's ``result``).
    """
    problem = ExcitationProblem(robot, config, C0=C0)
    program = build_excitation_program(problem, constraints, progress=progress)
    result = solve_excitation(program, solver, initial_guess)
    if raise_on_failure and not result.success:
        raise NoSolutionFound(result.message, result)
    return result
