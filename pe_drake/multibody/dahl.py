"""Pre-sliding friction (Dahl 1968): the friction torque of a joint as a state, not a curve.

Around a velocity reversal a Coulomb + viscous model jumps from −F_c to +F_c, while real
joints first deform elastically (pre-sliding) and the friction builds up over a small
displacement. The Dahl model describes that with one state F per joint:

    dF/dt = σ0 · v · (1 − F/F_c · sgn v)

F_c is the Coulomb level [N·m], σ0 the stiffness at rest [N·m/rad], and x_p = F_c/σ0 [rad]
the pre-sliding displacement over which F reaches 1 − 1/e of F_c after a reversal. With the
normalized state z = F/F_c:

    dz/dq = (1 − z · sgn(dq)) / x_p,

so z depends on the path q(t) only (rate-independent hysteresis), and along a monotone step
Δq it is integrated exactly: z ← s + (z − s)·exp(−|Δq|/x_p), s = sgn Δq
(:func:`dahl_state`). F = F_c·z is linear in F_c for a given x_p: the diagnosis searches
over x_p with the linear fit of F_c inside. In sliding z → sgn v, the Coulomb model of
:mod:`pe_drake.diagnosis.effects`, which is its x_p → 0 limit in sliding only: at rest
(dq = 0) z keeps the value it had when the joint stopped (±1 after sliding), so the Dahl
friction holds ±F_c where the Coulomb column tanh(v/v_s) gives 0 (the holding torque of
:mod:`pe_drake.diagnosis.holding`).

Sign convention (as every effect of :mod:`pe_drake.simulation.simulation`): F is a
resistive load the actuator must overcome, so the recorded torque holds +F and the joint
feels −F. :func:`dahl_friction_system` is the Drake system the simulator adds for it.
"""

from __future__ import annotations

import numpy as np

from pe_drake.multibody.drive_columns import COULOMB_VELOCITY_SCALE, coulomb_column
from pe_drake.multibody.rotor_coupling import rotor_coupling_system


def dahl_state(q: np.ndarray, x_p, z0=0.0) -> np.ndarray:
    """The normalized Dahl state z = F/F_c along a sampled path, integrated exactly.

    Args:
        q: joint positions, shape (T,) or (T, n) [rad or m]; between two samples the joint is
            taken to move monotonically.
        x_p: pre-sliding displacement F_c/σ0 [rad or m], a scalar or shape (n,) (or (G, n)
            for a grid of values, giving (T, G, n)).
        z0: initial state in [−1, 1].

    Returns:
        z, the shape of q (or (T, G, n) for a grid), each value in [−1, 1].
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
    −F_c·z (the torque the friction applies to the joints, to add to the plant's applied
    generalized force). Continuous state z, dz/dt = (v − |v|·z) / x_p, starting at 0.
    Joints with F_c = 0 carry a state that never matters.

    Args:
        coulomb: F_c per joint, shape (n,) [N·m].
        displacement: x_p = F_c/σ0 per joint, shape (n,) [rad], > 0.
        sliding: f_c per joint of a Coulomb friction f_c·tanh(v/v_s) without pre-sliding, shape
            (n,) [N·m or N] (the simulator's for prismatic joints, which Drake's DoorHinge cannot
            carry); None: none.
        velocity_scale: v_s of ``sliding`` [rad/s or m/s].
        drive_force: f(v) → (n,), a further velocity-dependent torque on the joints (a coupled
            motor's friction through its transmission, ``RobotModel.plant``); None: none.

    Returns:
        The system (pydrake is imported here so that importing this module stays light).
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

    The plant's applied generalized force becomes the diagram's exported input ``port_name``
    (the controller's torque) plus the friction torque −F_c·z.

    Args:
        coulomb: F_c per joint, shape (n,) [N·m]; joints with 0 carry no friction.
        stiffness: σ0 per joint, shape (n,) [N·m/rad], > 0 where F_c > 0.
        port_name: name of the exported input port.
        sliding, velocity_scale, drive_force: a Coulomb friction without pre-sliding and a further
            velocity-dependent torque (:func:`dahl_friction_system`).
        rotor_coupling: the off-diagonal rotor inertia C of a coupled transmission, (n, n)
            [kg·m²]: the summed torque then passes through
            :func:`~pe_drake.multibody.rotor_coupling.rotor_coupling_system` (None: no coupling).
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
