"""Motor currents to joint torques with per-joint drive gains, τ = k·i (``robot.drive_gains``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pe_drake.exceptions import DataError


def torque_from_current(current: np.ndarray, joints: Sequence[str], gains: Mapping[str, float], source: str,
                        what: str = "current.<joint> columns") -> np.ndarray:
    """τ = k_j · i_j per joint.

    Args:
        current: motor currents, shape (T, n) [A].
        joints: joint names, length n.
        gains: {joint: k} [N·m/A] (config ``robot.drive_gains``).
        source: the data file, for messages.
        what: where the currents came from, for messages.

    Returns:
        Joint torques, shape (T, n) [N·m].

    Raises:
        DataError: a joint without a gain (the missing joints are listed). Identifying
            unknown gains needs a known payload and is not done here.
    """
    missing = [j for j in joints if j not in gains]
    if missing:
        raise DataError(
            f"the data holds motor currents ({what}) but robot.drive_gains has no gain for "
            f"{', '.join(missing)}; give robot.drive_gains: {{joint: k [N·m/A]}} (τ = k·i) in the config",
            file=source, column=f"current.{missing[0]}",
        )
    return np.asarray(current, float) * np.array([float(gains[j]) for j in joints])
