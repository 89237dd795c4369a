"""Identify's drive terms as columns of the excitation's C, with their pullback.

With ``excitation.drive_terms`` set to ``friction`` or ``all``, C of Eq. (41) becomes [Ŷ_B | D]
with D identify's drive columns (:mod:`pe_drake.multibody.drive_columns`) at the T cost samples,
so cond(C) also counts how well the motion tells friction from inertia. On torque row j they
are tanh(v_j/v_s), v_j, 1 and v̇_j, times the row's noise weight; zero on ground-wrench rows.
The gradient adds to the regressor's pullback (Eq. 47) its part through v and v̇:

    ∂/∂v_j  tanh(v_j/v_s) = (1 − tanh²(v_j/v_s)) / v_s,   ∂/∂v_j  v_j = 1,   ∂/∂v̇_j  v̇_j = 1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pe_drake.multibody.drive_columns import (
    COULOMB_VELOCITY_SCALE,
    DriveLayout,
    DriveTermOptions,
    coulomb_column,
    drive_columns,
    drive_layout,
)

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


class DriveBlock:
    """The drive columns D of C at some samples, and the gradient through them.

    Args:
        row_scale: each row's weight (the :class:`SensorRows` scale), shape (r,), torque rows first.
    """

    def __init__(self, layout: DriveLayout, row_scale: np.ndarray):
        self.layout = layout
        self.row_scale = np.asarray(row_scale, float)
        self.count = layout.count

    def columns(self, v: np.ndarray, vd: np.ndarray) -> np.ndarray:
        """D at the samples (v, v̇), each (T, n): shape (T, r, d), rows weighted."""
        D = drive_columns(v, vd, self.layout, rows=len(self.row_scale))
        return D * self.row_scale[None, :, None]

    def pullback(self, v: np.ndarray, vd: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gradient of Σ G : D with respect to v and v̇, each (T, n); G has D's shape."""
        v_bar, vd_bar = np.zeros_like(v), np.zeros_like(vd)
        scale = self.layout.velocity_scale
        for k, (term, j) in enumerate(zip(self.layout.terms, self.layout.joints)):
            g = G[:, j, k] * self.row_scale[j]
            if term == "coulomb":
                v_bar[:, j] += g * (1.0 - coulomb_column(v[:, j], scale) ** 2) / scale
            elif term == "viscous":
                v_bar[:, j] += g
            elif term == "armature":
                vd_bar[:, j] += g
        return v_bar, vd_bar


def excitation_drive_block(robot: Robot, choice: str, base, rows, model) -> DriveBlock:
    """The drive block of ``excitation.drive_terms`` = ``choice`` ("none": no columns), the
    armature's separability decided on the problem's rows and base parameters."""
    options = DriveTermOptions(choice, COULOMB_VELOCITY_SCALE)
    layout = drive_layout(robot, base if choice == "all" else None, options, model, rows=rows)
    return DriveBlock(layout, rows.scale)
