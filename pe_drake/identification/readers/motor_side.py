"""Motor-side logs converted to the joint side with ``robot.transmission``: q = R⁻¹ θ_m,
τ = Rᵀ τ_m.

Columns, motors named by their joint: ``q_motor.<joint>`` [rad of the motor], optional
``v_motor.<joint>`` and ``vdot_motor.<joint>``, and ``tau_motor.<joint>`` [N·m of the motor] or
``current.<joint>`` [A] with ``robot.drive_gains``. A file is joint-side or motor-side, never
both: which side a torque was measured on decides what friction it holds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from pe_drake.exceptions import DataError
from pe_drake.identification.measurements import Measurement
from pe_drake.identification.readers.columns import read_mapped_csv

#: Motor-side column prefixes and the quantity each becomes once read (before the conversion).
MOTOR_COLUMNS = {"q_motor": "q", "v_motor": "v", "vdot_motor": "vdot", "tau_motor": "tau"}
JOINT_SIDE = ("q", "v", "vdot", "tau")


def is_motor_side(columns: Sequence[str]) -> bool:
    """The log names motor quantities (``q_motor.*``, ``tau_motor.*``, ...)."""
    return any(c.partition(".")[0] in MOTOR_COLUMNS for c in columns)


def motor_column_map(columns: Sequence[str], joints: Sequence[str], file: str) -> dict[str, str]:
    """{quantity.joint: column} reading a motor-side log's motor quantities under the joint-side
    names.

    Raises:
        DataError: joint-side columns beside motor ones, a joint without ``q_motor`` or without
            exactly one of ``tau_motor`` and ``current``.
    """
    mixed = [c for c in columns if c.partition(".")[0] in JOINT_SIDE]
    if mixed:
        raise DataError(f"the log mixes motor-side columns (q_motor.*, tau_motor.*) with joint-side ones "
                        f"({', '.join(mixed[:4])}); give one side per file", file=file, column=mixed[0])
    mapping = {"t": c for c in columns if c in ("t", "time", "timestamp")}
    for c in columns:
        prefix, _, joint = c.partition(".")
        if joint in joints and (prefix in MOTOR_COLUMNS or prefix == "current"):
            mapping[f"{MOTOR_COLUMNS.get(prefix, prefix)}.{joint}"] = c
    for j in joints:
        if f"q.{j}" not in mapping:
            raise DataError(f"the motor-side log has no q_motor.{j} column (motor angle [rad])", file=file,
                            column=f"q_motor.{j}")
        if (f"tau.{j}" in mapping) == (f"current.{j}" in mapping):
            raise DataError(f"the motor-side log must give exactly one of tau_motor.{j} and current.{j}", file=file,
                            column=f"tau_motor.{j}")
    return mapping


def read_motor_side_csv(path: str | Path, joints: Sequence[str], columns: Sequence[str],
                        drive_gains: Mapping[str, float] | None, transmission) -> Measurement:
    """A motor-side CSV as a joint-side :class:`Measurement`, converted with the robot's
    :class:`~pe_drake.multibody.transmission.Transmission`."""
    m = read_mapped_csv(path, joints, motor_column_map(columns, joints, str(path)), drive_gains)
    T = transmission

    def joint_side(x):
        return None if x is None else T.joint_positions(x)

    note = ("motor-side log converted to the joint side with robot.transmission (q = R⁻¹ θ_m, τ = Rᵀ τ_m"
            + (", coupled motors included" if T.coupled else "") + ")")
    return m.replace(q=joint_side(m.q), v=joint_side(m.v), vd=joint_side(m.vd),
                     tau=T.joint_torques(m.tau), notes=m.notes + (note,))
