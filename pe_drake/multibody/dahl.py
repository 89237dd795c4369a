"""Pre-sliding friction (Dahl 1968): the friction torque of a joint as a state, not a curve.

One state F per joint, dF/dt = σ0 · v · (1 − F/F_c · sgn v), with F_c the Coulomb level [N·m]
and x_p = F_c/σ0 [rad] the pre-sliding displacement. The normalized state z = F/F_c obeys
dz/dq = (1 − z · sgn(dq)) / x_p: it depends on the path only, and a monotone step Δq is
integrated exactly (:func:`dahl_state`). In sliding z → sgn v (the Coulomb model); at rest z
keeps its value, so the friction holds ±F_c where tanh(v/v_s) gives 0.

Sign convention (as :mod:`pe_drake.simulation.simulation`): F is a resistive load the actuator
must overcome, so the recorded torque holds +F and the joint feels −F.
"""

from __future__ import annotations

import numpy as np

from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, coulomb_column
from pe_drake.multibody.rotor_coupling import rotor_coupling_system


def dahl_state(q: np.ndarray, x_p, z0=0.0) -> np.ndarray:
    """The normalized Dahl state z = F/F_c ∈ [−1, 1] along a sampled path, integrated exactly.

    Args:
        q: joint positions, shape (T,) or (T, n) [rad or m], monotone between two samples.
        x_p: pre-sliding displacement F_c/σ0 [rad or m], a scalar or shape (n,) (or (G, n)
            for a grid of values, giving (T, G, n)).
        z0: initial state in [−1, 1].
    """
    q = np.asarray(q, float)
    flat = q.ndim == 1
    q2 = q[:, None] if flat else q
    x_p = np.asarray(x_p, float)
    z = np.broadcast_to(np.asarray(z0, float), np.broadcast_shapes(x_p.shape, q2.shape[1:])).copy()
    out = np.empty((q2.shape[0], *z.shape))
    out[0] = z
    dq = np.diff(q2, axis=0)
    for k in range(dq.shape[0]):
        s = np.sign(dq[k])
        z = s + (z - s) * np.exp(-np.abs(dq[k]) / x_p)
        out[k + 1] = z
    return out[:, 0] if flat and x_p.ndim == 0 else out


def dahl_friction_system(coulomb: np.ndarray, displacement: np.ndarray, sliding: np.ndarray | None = None,
                         velocity_scale: float = COULOMB_VELOCITY_SCALE, drive_force=None):
    """A Drake ``LeafSystem`` with the Dahl state of every joint.

    Input port ``state``: the plant's [q; v], size 2n. Output port ``generalized_force``:
    −F_c·z, the torque the friction applies to the joints. Continuous state z,
    dz/dt = (v − |v|·z) / x_p, starting at 0.

    Args:
        coulomb: F_c per joint, shape (n,) [N·m].
        displacement: x_p = F_c/σ0 per joint, shape (n,) [rad], > 0.
        sliding: f_c per joint of a Coulomb friction f_c·tanh(v/v_s) without pre-sliding,
            shape (n,) [N·m or N] (prismatic joints, which Drake's DoorHinge cannot carry).
        velocity_scale: v_s of ``sliding`` [rad/s or m/s].
        drive_force: f(v) → (n,), a further velocity-dependent torque on the joints (a coupled
            motor's friction through its transmission, ``RobotModel.plant``).
    """
    from pydrake.systems.framework import BasicVector, LeafSystem

    fc = np.asarray(coulomb, float).copy()
    xp = np.asarray(displacement, float).copy()
    n = fc.size
    f_s = np.zeros(n) if sliding is None else np.asarray(sliding, float).copy()

    class DahlFriction(LeafSystem):
        def __init__(self):
            super().__init__()
            self.state_port = self.DeclareVectorInputPort("state", BasicVector(2 * n))
            self.DeclareContinuousState(n)
            self.DeclareVectorOutputPort("generalized_force", BasicVector(n), self._force)

        def DoCalcTimeDerivatives(self, context, derivatives):
            v = self.state_port.Eval(context)[n:]
            z = context.get_continuous_state_vector().CopyToVector()
            derivatives.get_mutable_vector().SetFromVector((v - np.abs(v) * z) / xp)

        def _force(self, context, output):
            z = context.get_continuous_state_vector().CopyToVector()
            v = self.state_port.Eval(context)[n:]
            extra = drive_force(v) if drive_force is not None else 0.0
            output.SetFromVector(-fc * z - f_s * coulomb_column(v, velocity_scale) + extra)

    system = DahlFriction()
    system.set_name("pe_drake_dahl_friction")
    return system


def dahl_builder_hook(coulomb: np.ndarray, stiffness: np.ndarray, port_name: str, sliding: np.ndarray | None = None,
                      velocity_scale: float = COULOMB_VELOCITY_SCALE, drive_force=None,
                      rotor_coupling: np.ndarray | None = None):
    """A ``load_robot`` builder hook that adds :func:`dahl_friction_system` to a robot's diagram.

    The plant's applied generalized force becomes the exported input ``port_name`` plus −F_c·z.

    Args:
        coulomb: F_c per joint, shape (n,) [N·m]; joints with 0 carry no friction.
        stiffness: σ0 per joint, shape (n,) [N·m/rad], > 0 where F_c > 0.
        sliding, velocity_scale, drive_force: as :func:`dahl_friction_system`.
        rotor_coupling: the off-diagonal rotor inertia C of a coupled transmission, (n, n)
            [kg·m²], applied by :func:`~pe_drake.multibody.rotor_coupling.rotor_coupling_system`.
            The hook's ``systems`` list holds it once built: ``sync`` it with the plant's context.
    """
    coulomb = np.asarray(coulomb, float)
    stiffness = np.asarray(stiffness, float)

    def hook(builder, plant, scene_graph):
        from pydrake.systems.primitives import Adder  # lazy: pydrake stays out of `import pe_drake`

        x_p = np.where(coulomb > 0, coulomb / np.where(stiffness > 0, stiffness, 1.0), 1.0)
        dahl = builder.AddSystem(dahl_friction_system(coulomb, x_p, sliding, velocity_scale, drive_force))
        adder = builder.AddSystem(Adder(2, len(coulomb)))
        builder.Connect(plant.get_state_output_port(), dahl.get_input_port(0))
        builder.Connect(dahl.get_output_port(0), adder.get_input_port(1))
        builder.ExportInput(adder.get_input_port(0), port_name)
        if rotor_coupling is None:
            builder.Connect(adder.get_output_port(0), plant.get_applied_generalized_force_input_port())
            return
        coupling = builder.AddSystem(rotor_coupling_system(plant, rotor_coupling))
        hook.systems.append(coupling)
        builder.Connect(plant.get_state_output_port(), coupling.state_port)
        builder.Connect(adder.get_output_port(0), coupling.applied_port)
        builder.Connect(coupling.get_output_port(0), plant.get_applied_generalized_force_input_port())

    hook.systems = []
    return hook
