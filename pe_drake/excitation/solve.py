"""Solving a built excitation program with IPOPT or NLopt, and checking the result at 1 kHz.

:func:`solve_excitation` runs the solver (with a restart when NLopt's SLSQP stalls at its
start), re-checks every constraint between the samples and, where a sampled constraint is
violated there, adds those instants and solves again from that point within the same
iteration budget (:mod:`pe_drake.excitation.exchange`), falls back to the best feasible
point evaluated when the solver stops at an infeasible iterate, and reports it all in an
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

#: Quasi-Newton pairs IPOPT keeps (its limited-memory Hessian; IPOPT's default is 6), and in the
#: harmonic coordinates of :mod:`pe_drake.excitation.scaling` (issue 38), where 12 ended where
#: 30 did with a factorization up to 4× cheaper on the two-arm robot.
LBFGS_PAIRS, SCALED_LBFGS_PAIRS = 30, 12


def option_value(text: str) -> int | float | str:
    """An IPOPT option value written as text: an integer, a number or a word (IPOPT's options
    are typed, so "6" must reach it as 6)."""
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
        x: optimal alpha, shape ((2N+1)·n,).
        trajectory: the :class:`FourierTrajectory` of x.
        fun: criterion value at x.
        cond: cond(C) at x (C includes C0).
        cond_motion: cond of this motion's own Ŷ_B.
        success: x is a valid trajectory: every constraint holds at 1 kHz. When the solver
            stops early (iteration/time limit) at an infeasible iterate, x is the best
            feasible point it evaluated, if any.
        converged: the solver reported convergence to a local optimum.
        message: solver status, which constraint fails by how much, or the fallback used.
        status: Drake's solution result name, or "kStalled" (:mod:`pe_drake.excitation.stall`).
        nit: solver iterations (IPOPT: from its log; NLopt: None).
        nfev: cost evaluations.
        wall_time: [s].
        margins: {constraint: minimum margin at 1 kHz} (negative = violated), in the
            constraint's units (rad, rad/s, rad/s², m, N·m).
        singular_values: σ of C.
        solver: "ipopt" or "nlopt".
        raw: Drake's MathematicalProgramResult.
        solves: solver runs (1 + the exchange step's re-solves); ``nit`` sums them.
        exchange_samples: instants the exchange step added to the program.
        callback_seconds: time in the program's own callbacks (cost, limits, sampled
            constraints) during the solve [s]; the rest of ``wall_time`` is the solver's.
        far_from_convergence: the solver did not converge and the point returned has a
            cond-like criterion more than :data:`FAR_FROM_CONVERGENCE` times the best point
            within the joint limits it evaluated (:func:`far_from_convergence`): not a result,
            so ``success`` is False whatever the 1 kHz re-check says.
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
    callback_seconds: float = 0.0
    far_from_convergence: bool = False


def check_margins(
    problem: ExcitationProblem, alpha: np.ndarray, constraints: list[SampledConstraint] = (), rate: float = 1000.0
) -> dict[str, float]:
    """Minimum margin of each constraint over one period sampled at ``rate`` [Hz].

    Joint limits are reported per quantity (``position``, ``velocity``, ``acceleration``),
    the worst joint; negative means violated.
    """
    t = np.arange(0.0, problem.period, 1.0 / rate)
    basis = FourierBasis(problem.harmonics, problem.omega, t)
    return state_margins(problem.robot.limits, constraints, *basis.evaluate_alpha(np.asarray(alpha, float), problem.n))



class _IterationLimitWarningFilter(logging.Filter):
    """Drops Drake's warning on every IPOPT run that stops at ``max_iter``: its hint (IPOPT
    "performs badly if any variables are unbounded") does not apply to our coefficients,
    which the joint-limit rows bound, and :func:`solve_excitation` reports the iteration
    limit itself (``kIterationLimit`` in the message). Every other Drake message passes."""

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
    # SPRAL's default scaling (matching) redoes the symbolic analysis at every factorization;
    # without it IPOPT took the same iterates with ~40 % less linear-algebra time.
    options.SetOption(sid, "spral_scaling", "none")
    # 30 quasi-Newton pairs instead of IPOPT's 6: with the window rows of the joint limits
    # G1 ended 300 iterations at cond 254 (6 pairs), 226 (20), 205 (30), 200 (50; 40 % more
    # time per iteration than 30); the former sampled rows reached 209 with 6.
    options.SetOption(sid, "limited_memory_max_history", LBFGS_PAIRS)
    # The quasi-Newton pairs enter the augmented system as extra rows instead of through
    # Sherman-Morrison, which needs two back-solves per pair after every factorization
    # (60 of ~1 ms each per G1 iteration). The same steps in exact arithmetic; one G1 start
    # 47 → 32–34 s, the Panda 25 → 19 s (BUILD_NOTES.md).
    options.SetOption(sid, "limited_memory_aug_solver", "extended")
    # SPRAL amalgamates supernodes of fewer than 32 columns by default; our KKT systems are
    # a few hundred dense columns and thousands of nearly empty rows, and 4 halved the
    # factorization time (G1: 2.4 → 1.2 s per 90 iterations).
    options.SetOption(sid, "spral_nemin", 4)
    # No second-order corrections: they cost a constraint evaluation each and rarely rescued
    # a step. Measured with the cond criterion (before soft_cond became the default): from
    # three starts G1 ended at cond 209–211 instead of 227–232 with 10–20 % fewer
    # evaluations, and the Panda at 11.3–12.6 instead of 12.3–12.9.
    options.SetOption(sid, "max_soc", 0)
    for key, value in cfg.ipopt_options.items():  # the config's own, last (data, not a global)
        options.SetOption(sid, key, option_value(str(value)))
    if cfg.max_time > 0:
        options.SetOption(sid, "max_wall_time", float(cfg.max_time))
    # IPOPT reports no iteration count through Drake: its log file does (BUILD_NOTES.md).
    # In this process's own folder: a worker killed mid-solve leaves it to the next sweep.
    log_file = new_log_file()
    options.SetOption(CommonSolverOption.kPrintFileName, str(log_file))
    return _Backend(solver, options, log_file)


def _nlopt_backend(cfg: SolverConfig) -> _Backend:
    # pydrake is imported lazily so that `import pe_drake` stays light.
    from pydrake.solvers import NloptSolver, SolverOptions

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
    """The Drake solver named by ``cfg`` with its options, refused if this Drake lacks it."""
    if cfg.name == "ipopt":
        backend = _ipopt_backend(cfg)
    elif cfg.name == "nlopt":
        backend = _nlopt_backend(cfg)
    else:
        raise ConfigError(f"unknown solver '{cfg.name}'; valid: ipopt, nlopt")
    if not backend.solver.available() or not backend.solver.enabled():
        raise ConfigError(f"solver '{cfg.name}' is not available in this Drake build")
    return backend


def _run_solver(program: ExcitationProgram, solver, x0: np.ndarray, options):
    """One Drake solve of the program from x0, in the solver's coordinates of
    ``program.variable_scale`` (:mod:`pe_drake.excitation.scaling`) when it has one."""
    try:
        if program.variable_scale is None:
            return solver.Solve(program.prog, x0, options)
        return solve_scaled(
            solver, program.prog, program.alpha, program.variable_scale, x0, options, program.own_evaluators()
        )
    except CriterionStalled as stop:
        best = program.cost.candidates if program.cost is not None else []
        return StalledResult(program.alpha, best[0][1] if best else np.asarray(x0, float), str(stop))


def _solve_with_restarts(program: ExcitationProgram, backend: _Backend, cfg: SolverConfig, x0: np.ndarray):
    """Runs the solver from x0; returns Drake's result and a note on any restart ("" if none)."""
    problem = program.problem
    result = _run_solver(program, backend.solver, x0, backend.options)
    stalled = ""
    if cfg.name == "nlopt" and cfg.algorithm == "LD_SLSQP" and problem.num_evaluations <= 2:
        # NLopt's SLSQP sometimes stops after one evaluation with XTOL_REACHED: its first
        # QP step came back zero (seen at starts with gradients of ~1e6). Not a local
        # optimum: start again from the motion shrunk by 5 % toward its offsets (still
        # feasible: the limits are linear in alpha), then, if that stalls too, with MMA
        # (robust but slow with thousands of rows).
        nq0 = problem.n
        retry = x0.copy()
        retry[:-nq0] *= 0.95
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


#: The margins of :func:`check_margins` that are joint limits: a margin below 0 there is a
#: violation whatever the tolerance.
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
#: exchange step's re-solves (which otherwise would find no budget left whenever the first
#: run stops at its iteration limit, as it mostly does on G1 and Panda).
FIRST_SOLVE_SHARE = 0.9


def _solve_with_exchange(program, backend: _Backend, cfg: SolverConfig, x0: np.ndarray, check: _Check) -> _Run:
    """Solves, then, while the budget of ``cfg.max_iterations`` IPOPT iterations lasts, adds
    the instants where a sampled constraint is violated at ``check.rate``
    (:func:`~pe_drake.excitation.exchange.add_violated_samples`) and solves again from the
    last point; an unconverged run is also continued. Stops when a run converges with
    nothing violated, or when the budget is spent."""
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
        if program.cost is not None:  # a re-solve gets the stall rule's full allowance
            program.cost.best_history.clear()
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
    and vdot within the joint limits at ``rate`` [Hz] (they are linear in the motion).

    An iterate that overshoots a limit by a little (IPOPT stops at its iteration limit
    between two feasible points) becomes valid at almost the same cond.
    """
    alpha = np.asarray(alpha, float)
    t = np.arange(0.0, problem.period, 1.0 / rate)
    q, v, vd = FourierBasis(problem.harmonics, problem.omega, t).evaluate_alpha(alpha, problem.n)
    lim, q0 = problem.robot.limits, alpha[-problem.n :]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.concatenate(
            [
                np.where(q.max(0) > q0, (lim.q_upper - q0) / (q.max(0) - q0), np.inf),
                np.where(q.min(0) < q0, (q0 - lim.q_lower) / (q0 - q.min(0)), np.inf),
                lim.v_max / np.abs(v).max(0),
                lim.vd_max / np.abs(vd).max(0),
            ]
        )
    scale = min(1.0, float(np.min(ratios)) * (1 - 1e-9))
    out = alpha * scale
    out[-problem.n :] = q0
    return out


#: How far :func:`blend_toward_start` moves a nearly valid point toward the start (shares of
#: the way), in the order tried: the first valid blend is kept.
BLEND_SHARES = (0.001, 0.01, 0.05, 0.1, 0.25, 0.5, 0.75)


def blend_toward_start(
    program: ExcitationProgram, start: np.ndarray, target: np.ndarray, rate: float = 1000.0, tolerance: float = 1e-6
):
    """(share, point, margins) of the first ``target + share·(start − target)``, for the
    shares of :data:`BLEND_SHARES` in order, that holds every constraint at ``rate`` [Hz]
    (margins ≥ −``tolerance``), or None when none does or the start itself does not.

    The last resort of :func:`solve_excitation` when every point the solver evaluated
    crosses a sampled constraint between the samples by a little (e.g. capsules 0.1 mm
    inside the margin, iteration budget spent): the joint limits and the rest at the ends
    hold on the whole segment (they are linear in alpha), and a point a little closer to the
    valid start usually clears the rest."""
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

    When the solver stopped at an infeasible or unconverged iterate, the first valid point of:
    the iterate shrunk into the joint limits (:func:`shrink_into_limits`) when that keeps
    it valid, and the best points it evaluated that hold every constraint at ``check.rate``,
    replaces it (whichever has the lower criterion). When none of them is valid, the best
    point evaluated (or the iterate) moved a little toward the valid ``start``
    (:func:`blend_toward_start`) does.
    """
    problem = program.problem
    margins = check_margins(problem, x, program.constraints, rate=check.rate)
    if (solved and min(margins.values()) >= -check.tolerance) or program.cost is None:
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


#: A solve that did not converge ends "far from convergence" when the criterion at the point
#: it returns is more than this factor above the best point within the joint limits it
#: evaluated (issue 38: UR10 starts ended at cond 3,936 and 73,186 and a G1 start at 3,714,
#: each labelled valid, where their rivals reached 15 and 182).
FAR_FROM_CONVERGENCE = 2.0


def far_from_convergence(converged: bool, value: float, best_evaluated: float | None, criterion: str = "soft_cond") -> bool:
    """Whether a solve's returned point is no result: the solver did not converge and its
    criterion ``value`` is above :data:`FAR_FROM_CONVERGENCE` times ``best_evaluated`` (the
    lowest criterion among the points within the joint limits the solver evaluated; None when
    it evaluated none). A non-finite ``value`` is always far. For ``log_cond`` the factor is
    applied to cond (a difference of log 2); ``dopt`` (−log det, any sign) is only judged by
    finiteness."""
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
        solver: "ipopt", "nlopt", or a :class:`SolverConfig` with options.
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
        cfg = dataclasses.replace(cfg, ipopt_options={**cfg.ipopt_options, "limited_memory_max_history": SCALED_LBFGS_PAIRS})
    problem = program.problem
    x0 = problem.initial_guess() if initial_guess is None else np.asarray(initial_guess, float)
    if x0.shape != (problem.num_variables,):
        raise ConfigError(f"initial guess has shape {x0.shape}, expected ({problem.num_variables},)")
    backend = _backend(cfg)

    problem.num_evaluations = 0
    if program.cost is not None:
        program.cost.reset()
    check = _Check(check_rate, tolerance)
    reuse_freed_memory()  # a third of each evaluation went to faulting in fresh pages
    callbacks_before = program.callback_seconds()
    start = time.perf_counter()
    # NLopt's C callbacks swallow a Python exception (DRAKE_NOTES.md): the stall rule is IPOPT's.
    with single_threaded_blas(), stall_rule_active(program.cost, cfg.name == "ipopt"):
        if exchange:
            run = _solve_with_exchange(program, backend, cfg, x0, check)
        else:
            result, note = _solve_with_restarts(program, backend, cfg, x0)
            run = _Run(result, note, _iterations_from_log(backend.log_file), 1, 0)
    wall = time.perf_counter() - start
    result, stalled, nit = run.result, run.note, run.nit

    solved = result.is_success()
    x = np.asarray(result.GetSolution(program.alpha), float)
    with single_threaded_blas():  # BLAS's threads spin on a loaded machine: a G1 fallback's SVD took 0.7 CPU-s on them
        x, margins, fallback = _feasible_fallback(program, x, solved, check, x0)
        x, scale = keep_strictly_inside(problem, x)
        if scale < 1.0:
            margins = check_margins(problem, x, program.constraints, rate=check.rate)
            fallback += f"; motion scaled by 1 - {1 - scale:.2g} to keep strictly inside the joint limits"
        cost = problem.evaluate(x)
        cond_motion = _cond(np.linalg.svd(problem.regressor_block(x), compute_uv=False))
    # Nothing outside a joint limit is valid (issue 21): the solver's tolerance applies to
    # the other constraints only.
    violated = {k: m for k, m in margins.items() if m < (0.0 if k in JOINT_LIMIT_KEYS else -tolerance)}
    best = program.cost.best_value if program.cost is not None else None
    far = far_from_convergence(bool(solved), float(cost.value), best, problem.config.criterion)
    if far:
        fallback += (
            f"; FAR FROM CONVERGENCE: {problem.config.criterion} {cost.value:.5g} is more than "
            f"{FAR_FROM_CONVERGENCE:g}x the best point within the joint limits evaluated ({best:.5g}): not a result"
            if best is not None and np.isfinite(cost.value)
            else "; FAR FROM CONVERGENCE: the criterion is not finite: not a result"
        )
    return ExcitationResult(
        x=x,
        trajectory=problem.trajectory(x),
        fun=float(cost.value),
        cond=_cond(cost.singular_values),
        cond_motion=cond_motion,
        success=not violated and not far,
        converged=bool(solved),
        message=_message(cfg, result, violated, fallback, stalled),
        status=result.get_solution_result().name,
        nit=nit,
        nfev=problem.num_evaluations,
        wall_time=wall,
        margins=margins,
        singular_values=cost.singular_values,
        solver=cfg.name,
        raw=result,
        solves=run.solves,
        exchange_samples=run.added,
        callback_seconds=program.callback_seconds() - callbacks_before,
        far_from_convergence=far,
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
