"""What ``report.json`` of an optimized motion records: :class:`MotionReport`, a typed record
built from the solve, the ramps, the quality figures and the safety checks."""

from __future__ import annotations

import dataclasses
from typing import Any

from pe_drake.config import Config
from pe_drake.multibody.joint_limits import joint_unit


@dataclasses.dataclass(frozen=True)
class MotionReport:
    """The fields of ``report.json``, in the file's order (see the README's "Outputs").

    ``success``: a valid motion (every limit and constraint holds at 1 kHz); ``converged``: the
    solver also reached a local optimum. ``config``: the resolved config (fitted capsules and
    nominal posture included); ``unchecked``: what could not be checked for collision;
    ``ignored_pairs``: capsule pairs not checked (touching by design); ``shrunk_capsules``:
    fitted capsules made thinner; ``not_valid_for_hardware``: why it is refused (None: valid).
    """

    robot: str
    success: bool
    converged: bool
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
    ignored_pairs: list[dict[str, Any]]
    shrunk_capsules: dict[str, dict[str, float]]
    limit_margins: dict[str, Any]
    ramp_margins_1khz: dict[str, float] | None
    motion: dict[str, Any] | None
    quality: dict[str, Any] | None
    unchecked: list[str]
    not_valid_for_hardware: str | None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def assumed_defaults(config: Config, joint_names, kinds=None) -> list[str]:
    """Limits pe_drake assumed because neither the model nor the config gives them (``kinds``:
    "revolute" or "prismatic" per joint, for the units; None: all revolute)."""
    r = config.robot
    kinds = list(kinds) if kinds is not None else ["revolute"] * len(joint_names)
    missing = {kind: [j for j, k in zip(joint_names, kinds) if k == kind and j not in r.acceleration_limits]
               for kind in ("revolute", "prismatic")}
    parts = [f"{r.default_acceleration_limit:g} {joint_unit(kind, 2)} assumed for {', '.join(names)}"
             for kind, names in missing.items() if names]
    if not parts:
        return []
    return [f"acceleration limit {'; '.join(parts)} "
            "(robot.default_acceleration_limit; set robot.acceleration_limits from the robot's datasheet)"]


def start_records(ms) -> list[dict[str, Any]]:
    """One entry per start of a :class:`~pe_drake.excitation.multistart.MultiStartResult`."""
    return [
        {"seed": s.seed, "cond": s.cond, "success": s.success, "time_s": s.wall_time, "task_time_s": s.task_time,
         "worker": s.worker, "criterion_value": s.fun, "message": s.message, "lost": s.lost}
        for s in ms.starts
    ]
