"""The ground wrench a simulated run records.

A humanoid identified from its feet's force/torque sensors (or a force plate) logs the wrench
the ground applies. In simulation the feet are the weld of the root link, so the wrench is
Drake's reaction at that weld (:func:`pe_drake.multibody.wrench.weld_reaction`), recorded like
the torque (centred on the sample instant), plus the sensor's white noise and constant
offset from the truth's ``noise`` (``force_std``, ``moment_std``, ``wrench_offset``).
"""

from __future__ import annotations

import numpy as np

from pe_drake.multibody.wrench import weld_reaction
from pe_drake.simulation.truth import Truth


def recorded_wrench(true_robot, truth: Truth, q: np.ndarray, v: np.ndarray, applied: np.ndarray) -> np.ndarray:
    """The logged ground wrench of a run, shape (K, 6) [N, N·m] (``wrench.*`` column order).

    Args:
        true_robot: the simulated :class:`~pe_drake.multibody.robot.Robot` (its context holds
            the true inertias).
        truth: the validated truth (noise, offset, seed, ``record_command``).
        q, v: true positions and velocities at the control instants, (K, n).
        applied: the generalized forces applied over [t_k, t_k + h), (K, n) [N·m].
    """
    # The acceleration, and so the reaction, jumps at t_k when the held command changes: the
    # average of the reactions under the commands before and after t_k is centred on t_k, like
    # the logged torque (unless the truth records the raw command).
    wrench = weld_reaction(true_robot, q, v, applied, centred=not truth.record_command)
    noise = truth.noise
    # Its own random stream: the q, tau and v noise of earlier files stays as it was.
    rng = np.random.default_rng(np.random.SeedSequence(truth.seed).spawn(3)[2])
    std = np.repeat([noise.force_std, noise.moment_std], 3)
    offset = np.asarray(noise.wrench_offset, float) if noise.wrench_offset else np.zeros(6)
    return wrench + offset + rng.normal(size=wrench.shape) * std
