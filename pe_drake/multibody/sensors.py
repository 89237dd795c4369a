"""What the robot measures: joint torques, the ground wrench, or both.

Each gives the rows of y = A(q, v, vdot) φ: ``joint_torque`` τ = Y φ (Eq. 1), ``base_wrench``
w = Y_0 φ + w_static (:mod:`pe_drake.multibody.wrench`), or ``both``. Rows are divided by their
sensor noise σ, so cond(C) does not depend on units and least squares is the weighted estimate.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from pe_drake.config import MEASUREMENTS, ExcitationConfig
from pe_drake.config_sections import noise_vector
from pe_drake.exceptions import ConfigError
from pe_drake.multibody.base_parameters import RANK_GAP_RATIO, BaseParameters, compute_base_parameters
from pe_drake.multibody.regressor import Kinematics, RegressorModel
from pe_drake.multibody.wrench import WRENCH_COLUMNS

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

__all__ = ["MEASUREMENTS", "WRENCH_RANK_TOLERANCE", "MeasurementType", "SensorRows", "measurement_type"]

#: Relative tolerance on the pivoted-QR diagonal for rows that include the ground wrench. On
#: G1's arms 1e-8 keeps a direction whose effect (~1e-5 N·m) is far below any force/torque
#: sensor and that pins cond(C) above 1e5; the next one is at 0.39 (BUILD_NOTES.md).
WRENCH_RANK_TOLERANCE = 1e-3


@dataclasses.dataclass(frozen=True)
class MeasurementType:
    """A measurement type and its sensor noise σ (the row weights)."""

    kind: str = "joint_torque"
    torque_std: float | tuple[float, ...] = 1.0  # [N·m or N], one value or one per joint
    force_std: float = 0.5  # [N], of the ground-wrench sensor
    moment_std: float = 0.05  # [N·m], of the ground-wrench sensor

    def __post_init__(self):
        if self.kind not in MEASUREMENTS:
            raise ConfigError(f"measurement '{self.kind}' is not one of {', '.join(MEASUREMENTS)}")
        for name in ("torque_std", "force_std", "moment_std"):
            values = getattr(self, name)
            for value in values if isinstance(values, tuple) else (values,):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                    raise ConfigError(f"measurement {name} must be a positive number, got {value!r}")

    @property
    def torques(self) -> bool:
        """Whether the joint torques are measured."""
        return self.kind in ("joint_torque", "both")

    @property
    def wrench(self) -> bool:
        """Whether the ground wrench is measured."""
        return self.kind in ("base_wrench", "both")

    def row_names(self, joint_names) -> tuple[str, ...]:
        """Names of the rows of one sample: the joints' torques, then :data:`WRENCH_COLUMNS`."""
        return (tuple(joint_names) if self.torques else ()) + (WRENCH_COLUMNS if self.wrench else ())

    def row_std(self, n: int) -> np.ndarray:
        """σ of each row of one sample, shape (r,)."""
        parts = [np.broadcast_to(np.asarray(self.torque_std, float), (n,))] if self.torques else []
        if self.wrench:
            parts.append(np.repeat([self.force_std, self.moment_std], 3))
        return np.concatenate(parts)


def measurement_type(config: ExcitationConfig, kind: str | None = None, joint_names=None) -> MeasurementType:
    """The :class:`MeasurementType` of an excitation config (``kind`` overrides ``measurement``).

    ``joint_names`` resolve a per-joint torque noise table (without them it needs ``all``)."""
    noise = config.noise_std
    torque = noise.torque
    if isinstance(torque, dict):
        names = tuple(joint_names) if joint_names is not None else tuple(k for k in torque if k != "all")
        torque = tuple(noise_vector(torque, names)) if names else noise_vector(torque, ["all"])[0]
    return MeasurementType(kind or config.measurement, torque, noise.force, noise.moment)


class SensorRows:
    """The noise-scaled rows A^(t) = diag(1/σ) [Y^(t); Y_0^(t)] of a measurement, and adjoint."""

    def __init__(self, model: RegressorModel, measurement: MeasurementType | None = None):
        self.model = model
        self.measurement = measurement or MeasurementType()
        self.n = model.n
        self.num_params = model.num_params
        self.scale = 1.0 / self.measurement.row_std(model.n)  # (r,)
        self.num_rows = len(self.scale)
        # Joint torques with σ = 1 (the default) need no scaling: skip two passes over (T, r, p).
        self._unit_scale = bool(np.all(self.scale == 1.0))

    def kinematics(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> Kinematics:
        """:meth:`RegressorModel.kinematics`."""
        return self.model.kinematics(q, v, vd)

    def rows(self, kin: Kinematics, scaled: bool = True, columns: np.ndarray | None = None) -> np.ndarray:
        """A, shape (T, r, 10·nb) (or (T, r, len(columns))), divided by σ if ``scaled``."""
        parts = []
        if self.measurement.torques:
            parts.append(self.model.regressor(kin, columns))
        if self.measurement.wrench:
            parts.append(self.model.wrench_regressor(kin, columns))
        A = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=1)
        return A * self.scale[:, None] if scaled and not self._unit_scale else A

    def __call__(self, q: np.ndarray, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """The scaled rows at (q, v, vdot), shape (T, r, 10·nb)."""
        return self.rows(self.kinematics(q, v, vd))

    def pullback(self, kin: Kinematics, Z: np.ndarray,
                 columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gradient of Σ_t Z^(t) : A^(t) (scaled rows) with respect to q, v and vdot, each (T, n).

        Args:
            Z: weights, shape (T, r, 10·nb), or (T, r, len(columns)) with ``columns``.
            columns: the columns Z is given at (the others are zero).
        """
        if not self._unit_scale:
            Z = Z * self.scale[:, None]
        n = self.n if self.measurement.torques else 0
        Z_tau = Z[:, :n] if self.measurement.torques else None
        Z_wrench = Z[:, n:] if self.measurement.wrench else None
        return self.model.pullback(kin, Z_tau, Z_wrench, columns)

    def base_parameters(self, *, seed: int = 0, rank_tolerance: float | None = None,
                        gap_ratio: float | None = RANK_GAP_RATIO) -> BaseParameters:
        """The base parameters of these rows (their own pivoted QR, Eq. 2).

        ``rank_tolerance`` defaults to 1e-8 for joint torques, :data:`WRENCH_RANK_TOLERANCE` with
        the wrench.
        """
        if rank_tolerance is None:
            rank_tolerance = WRENCH_RANK_TOLERANCE if self.measurement.wrench else 1e-8
        samples = max(20, int(np.ceil(4 * self.num_params / self.num_rows)))
        return compute_base_parameters(self.model.robot, samples=samples, seed=seed,
                                       rank_tolerance=rank_tolerance, gap_ratio=gap_ratio,
                                       model=self.model, rows=self,
                                       measurement=self.measurement.kind)


def measurement_base_parameters(robot: Robot, measurement: str = "joint_torque",
                                model: RegressorModel | None = None, *,
                                rows: SensorRows | None = None) -> BaseParameters:
    """The base parameters a measurement identifies (Eq. 2 on its ``rows``, default unit noise)."""
    model = model or (rows.model if rows is not None else RegressorModel(robot))
    if measurement == "joint_torque":
        return compute_base_parameters(robot, model=model)
    return (rows or SensorRows(model, MeasurementType(measurement))).base_parameters()
