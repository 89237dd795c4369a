"""The measured channels of a run as rows of the identification model.

A run measures joint torques, the ground wrench, or both (``measurement`` of
:mod:`pe_drake.multibody.sensors`). Each channel c of each sample gives one equation
y_c = A_c(q, v, vdot) φ + ρ_c:

- joint torque j: y = τ_j, A = row j of Y (Eq. 1);
- ground-wrench component (:data:`~pe_drake.multibody.wrench.WRENCH_COLUMNS`):
  y = w − w_static, A = the row of Y_0, where w_static is the a-priori model's weight of the
  bodies no excited joint moves (:func:`~pe_drake.multibody.wrench.static_wrench`).

A constant offset of the force/torque sensor adds to w_static: it cannot be told from the
total mass and the horizontal centre of mass of the moving bodies (the fz, mx, my offsets
lie in the span of Y_0), so zero the sensors with the feet unloaded, or measure the offset
in a static pose and subtract it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.exceptions import DataError
from pe_drake.multibody.sensors import MeasurementType
from pe_drake.multibody.wrench import WRENCH_COLUMNS, static_wrench

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

#: Samples per regressor evaluation (bounds the memory of (S, r, 10·nb) arrays).
CHUNK = 2000


def channel_names(robot: Robot, measurement: str) -> tuple[str, ...]:
    """Names of the channels of one sample: the joints (their torques), then :data:`WRENCH_COLUMNS`."""
    return MeasurementType(measurement).row_names(robot.joint_names)


def measured_values(robot: Robot, data, measurement: str) -> np.ndarray:
    """y of every sample, shape (S, r): torques, then the wrench minus the static bodies' weight.

    Raises:
        DataError: the data lacks the channels the measurement needs (naming the columns).
    """
    kind = MeasurementType(measurement)
    parts = []
    if kind.torques:
        if data.tau is None:
            raise DataError(f"measurement '{measurement}' needs the joint torques (tau.<joint> "
                            "columns); this run has none: use --measurement base_wrench",
                            file=data.source)
        parts.append(np.asarray(data.tau, float))
    if kind.wrench:
        wrench = getattr(data, "wrench", None)
        if wrench is None:
            raise DataError(f"measurement '{measurement}' needs the ground wrench (columns "
                            f"{', '.join(WRENCH_COLUMNS)}); this run has none: use --measurement "
                            "joint_torque", file=data.source)
        parts.append(np.asarray(wrench, float) - static_wrench(robot))
    return np.concatenate(parts, axis=1)
