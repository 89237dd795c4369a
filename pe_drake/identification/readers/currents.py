"""Motor currents to joint torques with per-joint drive gains, τ = k·i (``robot.drive_gains``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pe_drake.exceptions import DataError


def torque_from_current(current: np.ndarray, joints: Sequence[str], gains: Mapping[str, float], source: str,
                        what: str = "current.<joint> columns") -> np.ndarray:
    """Joint torques τ = k_j · i_j [N·m] of motor currents (T, n) [A], gains {joint: k} [N·m/A].

    Raises:
        DataError: a joint without a gain (the missing joints are listed).
    """
    missing = [j for j in joints if j not in gains]
    if missing:
        raise DataError(f"the data holds motor currents ({what}) but robot.drive_gains has no gain "
                        f"for {', '.join(missing)}; give robot.drive_gains: {{joint: k [N·m/A]}} "
                        "(τ = k·i) in the config", file=source, column=f"current.{missing[0]}")
    return np.asarray(current, float) * np.array([float(gains[j]) for j in joints])
