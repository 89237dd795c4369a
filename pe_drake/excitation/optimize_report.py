"""What ``report.json`` of an optimized motion records: :class:`MotionReport`, a typed record
built from the solve, the ramps, the quality figures and the safety checks."""

from __future__ import annotations

import dataclasses
from typing import Any

from pe_drake.config import Config


@dataclasses.dataclass(frozen=True)
class MotionReport:
    """The fields of ``report.json``, in the file's order (see the README's "Outputs").

    ``config`` is the resolved config the motion was solved with (fitted capsules and a
    chosen nominal posture included); ``limit_margins`` the position margin and velocity,
    acceleration and effort fractions the limits were used with (and which were assumed);
    ``ramp_margins_1khz`` the smallest margins over the ramps; ``unchecked`` lists what could not be checked for
    collision; ``not_valid_for_hardware`` the reason the motion is refused (None: valid).
    """

    robot: str
    success: bool
    message: str
    status: Any
    solver: str
    criterion: str
    measurement: str
    cond: float
    cond_motion: float
    criterion_value: float
    iterations: int | None
    evaluations: int
    seed: int
    solve_time_s: float
    multistart_time_s: float
    total_time_s: float
    executor: dict[str, Any]
    starts: list[dict[str, Any]]
    margins_1khz: dict[str, float]
    base_parameters: int
    base_parameter_names: list[str]
    singular_values: list[float]
    prior: list[str]
    config: dict[str, Any]
    assumed_defaults: list[str]
    fitted_capsules: str | None
    limit_margins: dict[str, Any]
    ramp_margins_1khz: dict[str, float] | None
    motion: dict[str, Any] | None
    quality: dict[str, Any] | None
    unchecked: list[str]
    not_valid_for_hardware: str | None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def assumed_defaults(config: Config, joint_names) -> list[str]:
    """Limits pe_drake assumed because neither the model nor the config gives them."""
    r = config.robot
    missing = [j for j in joint_names if j not in r.acceleration_limits]
    if not missing:
        return []
    return [
        f"acceleration limit {r.default_acceleration_limit:g} rad/s² assumed for {', '.join(missing)} "
        "(robot.default_acceleration_limit; set robot.acceleration_limits from the robot's datasheet)"
    ]


def start_records(ms) -> list[dict[str, Any]]:
    """One entry per start of a :class:`~pe_drake.excitation.multistart.MultiStartResult`."""
    return [
        {"seed": s.seed, "cond": s.cond, "success": s.success, "time_s": s.wall_time, "task_time_s": s.task_time,
         "worker": s.worker, "criterion_value": s.fun, "message": s.message, "lost": s.lost}
        for s in ms.starts
    ]
