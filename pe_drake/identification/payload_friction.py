"""Per-joint drive terms as nuisance columns of the payload fit: Coulomb, viscous, offset.

τ_drive,j = f_c,j tanh(v_j / v_s) + f_v,j v_j + o_j is linear in θ = [f_c (n), f_v (n), o (n)]:
3n extra columns shared by every run, from :mod:`pe_drake.multibody.drive_columns`.
"""

from __future__ import annotations

import numpy as np

from pe_drake.multibody.drive_columns import UNITS, DriveLayout, drive_columns

#: The drive terms, in column order (each one column per joint).
FRICTION_TERMS = ("coulomb", "viscous", "offset")


def friction_columns(v: np.ndarray, velocity_scale: float, terms=FRICTION_TERMS) -> np.ndarray:
    """The drive-term regressor, shape (S, n, len(terms)·n): column k·n + j acts on joint j only.

    Args:
        v: joint velocities, (S, n) [rad/s].
        velocity_scale: v_s of the smoothed Coulomb law [rad/s], > 0.
        terms: a subset of :data:`FRICTION_TERMS`, in that order (checked by ``PayloadOptions``).
    """
    v = np.atleast_2d(np.asarray(v, float))
    n = v.shape[1]
    layout = DriveLayout(tuple(t for t in terms for _ in range(n)), tuple(j for _ in terms for j in range(n)),
                         tuple(str(j) for j in range(n)), tuple(UNITS[t][0] for t in terms for _ in range(n)),
                         float(velocity_scale))
    return drive_columns(v, v, layout)


def drive_names(joints, terms=FRICTION_TERMS) -> tuple[str, ...]:
    """``<term>.<joint>`` in the column order of :func:`friction_columns`."""
    return tuple(f"{t}.{j}" for t in terms for j in joints)
