"""Excitation of a payload alone: a short motion that makes its 10 parameters well determined.

With the arm's parameters known, a payload run must determine the payload link's 10 regressor
columns Y_L (:mod:`pe_drake.multibody.payload`). The arm's excitation machinery is reused as it
is, with the combinations of those columns the torques determine as its "base parameters"
(:func:`~pe_drake.multibody.payload.payload_base_parameters`), so the criterion and its gradient
are those of Y_L; every constraint of the arm applies.

Expected σ (:func:`expected_payload_std`): Cov(φ_L) = (Y_Lᵀ Σ⁻¹ Y_L)⁻¹ over the whole motion,
times 2 when an unloaded run of the same motion is fitted with it (the difference of two noisy
runs), carried to mass, centre of mass and central inertia at a nominal payload.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError, NoSolutionFound
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.program import build_excitation_program
from pe_drake.excitation.ramp import RAMP_DURATIONS, RampedMotion, choose_ramp_duration
from pe_drake.excitation.solve import ExcitationResult, solve_excitation
from pe_drake.excitation.trajectory_file import save_trajectory, write_motion_csv
from pe_drake.io_utils import finite_json
from pe_drake.multibody.payload import (
    PayloadInertia,
    box_inertia,
    central_jacobian,
    determined_std,
    link_columns,
    payload_base_parameters,
    payload_parameter_names,
    undetermined_parameters,
)
from pe_drake.multibody.regressor import RegressorModel

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Default period of a payload motion [s] and its harmonics.
PAYLOAD_PERIOD_S = 6.0
PAYLOAD_HARMONICS = 5
#: Longest payload motion by default, ramps included [s].
MAX_PAYLOAD_DURATION_S = 15.0
#: The payload at which expected σ are linearized when none is given: 1 kg, 0.1 m cube,
#: centre of mass 5 cm from the link origin along z.
NOMINAL_PAYLOAD = PayloadInertia(1.0, np.array([0.0, 0.0, 0.05]), box_inertia(1.0, [0.1, 0.1, 0.1]))


def payload_excitation_config(**changes) -> ExcitationConfig:
    """The arm's :class:`ExcitationConfig` with the payload defaults: a 6 s period, 5
    harmonics, 60 cost samples, 300 constraint samples, ramps on; ``changes`` override."""
    values = dict(harmonics=PAYLOAD_HARMONICS, omega=2 * math.pi / PAYLOAD_PERIOD_S, cost_samples=60,
                  constraint_samples=300, ramp=True, criterion="dopt")
    values.update(changes)
    return ExcitationConfig(**values)


@dataclasses.dataclass(frozen=True)
class PayloadStd:
    """Expected σ of a payload's mass [kg], centre of mass (3,) [m] and central inertia (6,)
    [kg·m²] ([Ixx, Iyy, Izz, Ixy, Ixz, Iyz]), at ``nominal``, for ``noise_std`` [N·m]."""

    mass_std: float
    com_std: np.ndarray
    inertia_about_com_std: np.ndarray
    nominal: PayloadInertia
    noise_std: np.ndarray
    paired: bool
    rate_hz: float
    undetermined: tuple[str, ...] = ()  # parameters no motion of the robot excites (their σ: NaN)

    def summary_lines(self) -> list[str]:
        p = self.nominal
        how = "with an unloaded run of the same motion" if self.paired else "arm model exact"
        lines = [
            f"expected payload σ ({how}; {self.rate_hz:g} Hz, torque noise "
            f"{np.array2string(self.noise_std, precision=3)} N·m; at {p.mass:g} kg, CoM {p.com.tolist()} m):",
            f"  mass {self.mass_std * 1e3:.3g} g ({100 * self.mass_std / p.mass:.3g} %), "
            f"CoM {np.array2string(self.com_std * 1e3, precision=3)} mm, "
            f"inertia {np.array2string(self.inertia_about_com_std, precision=3)} kg·m²"
            # the legend only where a σ is NaN: printed always, it read as if something were undetermined
            + (" (nan: not determined)" if np.isnan(self.inertia_about_com_std).any() else ""),
        ]
        if self.undetermined:
            lines.append(undetermined_note(self.undetermined))
        return lines

    def to_dict(self) -> dict:
        return finite_json({"mass_std": self.mass_std, "com_std": self.com_std, "inertia_about_com_std":
                            self.inertia_about_com_std, "nominal_mass": self.nominal.mass, "nominal_com": self.nominal.com,
                            "noise_std": self.noise_std, "paired_with_unloaded_run": self.paired,
                            "rate_hz": self.rate_hz, "not_determined": list(self.undetermined)})


def undetermined_note(names) -> str:
    """What the user is told about payload parameters no motion of the robot excites."""
    return (f"not determined by any motion of this robot ({len(names)} of 10): {', '.join(names)}: they never change "
            "its joint torques (e.g. all axes vertical), so they are left out of the motion's criterion and the fit; "
            "it needs no value for them: take them from CAD where another robot or a controller needs them")


def expected_payload_std(robot: Robot, link: str, motion, *, noise_std=0.04, nominal: PayloadInertia | None = None,
                         rate_hz: float = 1000.0, paired: bool = True, model: RegressorModel | None = None) -> PayloadStd:
    """Expected σ of the payload identified from ``motion`` (module docstring).

    Args:
        motion: a :class:`~pe_drake.excitation.ramp.RampedMotion` or a FourierTrajectory
            (one period).
        noise_std: torque noise σ_j [N·m], scalar or (n,).
        nominal: the payload to linearize at (default :data:`NOMINAL_PAYLOAD`).
        rate_hz: data rate [Hz].
        paired: an unloaded run of the same motion is fitted with it (×2 on the covariance).
    """
    nominal = nominal or NOMINAL_PAYLOAD
    sigma = np.broadcast_to(np.asarray(noise_std, float), (robot.n,)).copy()
    duration = motion.duration if hasattr(motion, "duration") else motion.period
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    model = model or RegressorModel(robot)
    cols = link_columns(robot, link)
    base = payload_base_parameters(robot, link, model)
    K_L = base.K[:, cols]  # φ_B = K_L φ_L: what the torques determine
    info = np.zeros((base.count, base.count))
    for s in range(0, t.size, 2000):
        q, v, vd = motion.evaluate(t[s : s + 2000])
        YB = (base.reduce(model(q, v, vd)) / sigma[None, :, None]).reshape(-1, base.count)  # Y_L = Y_B K_L
        info += YB.T @ YB
    cov_B = np.linalg.pinv(info) * (2.0 if paired else 1.0)
    std = determined_std(central_jacobian(nominal.phi), K_L, cov_B)
    names = payload_parameter_names(link)
    undetermined = tuple(names[i] for i in undetermined_parameters(base, robot, link))
    return PayloadStd(float(std[0]), std[1:4], std[4:10], nominal, sigma, paired, rate_hz, undetermined)


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadMotionPlan:
    """A payload motion for ``link``: the solve's result (cond of Y_L), the controller motion
    with its ramps, the expected σ, the criterion minimized and ``wall_time`` [s]."""

    link: str
    result: ExcitationResult
    motion: RampedMotion
    expected: PayloadStd
    wall_time: float
    criterion: str = "cond"

    def write(self, out: str | Path, robot: Robot, csv_rate: float = 1000.0) -> list[Path]:
        """trajectory.json (with ``payload_link``) and trajectory.csv in ``out``."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        save_trajectory(out / "trajectory.json", robot, self.result.trajectory, cond=self.result.cond,
                        cond_motion=self.result.cond_motion, payload_link=self.link,
                        payload_expected_std=self.expected.to_dict(), **self.motion.to_dict())
        write_motion_csv(out / "trajectory.csv", robot.joint_names, self.motion, csv_rate)
        return [out / "trajectory.json", out / "trajectory.csv"]


def optimize_payload_motion(robot: Robot, link: str, config: ExcitationConfig | None = None,
                            solver: str | SolverConfig | None = None, *, constraints=(),
                            max_duration: float = MAX_PAYLOAD_DURATION_S, noise_std=0.04,
                            nominal: PayloadInertia | None = None, raise_on_failure: bool = True) -> PayloadMotionPlan:
    """Optimizes a payload motion for ``link`` (module docstring).

    Args:
        link: the payload link (a body in ``robot.body_names``).
        config: excitation settings (default :func:`payload_excitation_config`).
        solver: "ipopt", "nlopt" or a :class:`SolverConfig` (default IPOPT, 150 iterations).
        constraints: the sampled constraints (collision, balance, ...) as for the arm.
        max_duration: longest motion, ramps included [s].
        noise_std, nominal: for the expected σ (:func:`expected_payload_std`).
        raise_on_failure: raise :class:`NoSolutionFound` when no valid motion was found.

    Raises:
        ConfigError, InfeasibleError: no room for the ramps within ``max_duration``; no ramp works.
    """
    start = time.perf_counter()
    config = config or payload_excitation_config()
    solver = solver or SolverConfig(max_iterations=150, verbose=False)
    period = 2 * math.pi / config.omega
    durations = [d for d in RAMP_DURATIONS if period * config.periods + 2 * d <= max_duration]
    if config.ramp and not durations:
        raise ConfigError(f"a payload motion of {config.periods} period(s) of {period:.3g} s leaves no room for "
                          f"ramps of at least {RAMP_DURATIONS[0]:g} s within {max_duration:g} s: shorten the period "
                          "(a larger omega) or raise max_duration")
    problem = ExcitationProblem(robot, config, base=payload_base_parameters(robot, link))
    program = build_excitation_program(problem, list(constraints))
    result = solve_excitation(program, solver)
    if not result.success and raise_on_failure:
        raise NoSolutionFound(result.message, result)
    if config.ramp:
        motion, _ = choose_ramp_duration(result.trajectory, robot.limits, list(constraints),
                                         periods=config.periods, durations=durations)
    else:
        motion = RampedMotion(result.trajectory, config.periods, 0.0)
    expected = expected_payload_std(robot, link, motion, noise_std=noise_std, nominal=nominal, model=problem.model)
    return PayloadMotionPlan(link, result, motion, expected, time.perf_counter() - start, config.criterion)
