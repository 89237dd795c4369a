"""The coupling entries of a reflected rotor inertia, for Drake's continuous plant (issue 36).

A motor that turns several joints adds Rᵀ diag(I_m) R q̈ to the joint torques; Drake holds the
diagonal per joint, not the off-diagonal part C. The true dynamics are (M_d + C) q̈ = u − ID_0,
M_d the plant's mass matrix and ID_0 the inverse dynamics at q̈ = 0 with the force elements.
Adding f = −C a, a = (M_d + C)⁻¹(u − ID_0), to u makes the plant give exactly q̈ = a.
"""

from __future__ import annotations

import numpy as np


def rotor_coupling_system(plant, coupling: np.ndarray):
    """A Drake ``LeafSystem``: inputs ``state`` ([q; v]) and ``applied`` (u, size n), output
    ``generalized_force`` u − C a (module docstring).

    Args:
        plant: the finalized continuous MultibodyPlant whose velocities are the joints'.
        coupling: C, (n, n) [kg·m²], symmetric with a zero diagonal.

    Returns:
        The system; call its ``sync(plant_context)`` once the plant's parameters are set
        (perturbed inertias are set after the diagram is built).
    """
    from pydrake.multibody.tree import MultibodyForces  # lazy: pydrake stays out of `import pe_drake`
    from pydrake.systems.framework import BasicVector, LeafSystem

    C = np.asarray(coupling, float).copy()
    n = C.shape[0]

    class RotorCoupling(LeafSystem):
        def __init__(self):
            super().__init__()
            self.state_port = self.DeclareVectorInputPort("state", BasicVector(2 * n))
            self.applied_port = self.DeclareVectorInputPort("applied", BasicVector(n))
            self.DeclareVectorOutputPort("generalized_force", BasicVector(n), self._force)
            self.scratch = plant.CreateDefaultContext()
            self.forces = MultibodyForces(plant)

        def sync(self, plant_context) -> None:
            """Copies the plant's parameters (body inertias, rotor inertias, damping) to the scratch context."""
            self.scratch.SetTimeStateAndParametersFrom(plant_context)

        def _force(self, context, output):
            x = self.state_port.Eval(context)
            u = self.applied_port.Eval(context)
            plant.SetPositionsAndVelocities(self.scratch, x)
            plant.CalcForceElementsContribution(self.scratch, self.forces)
            id0 = plant.CalcInverseDynamics(self.scratch, np.zeros(n), self.forces)
            a = np.linalg.solve(plant.CalcMassMatrix(self.scratch) + C, u - id0)
            output.SetFromVector(u - C @ a)

    system = RotorCoupling()
    system.set_name("pe_drake_rotor_coupling")
    return system
