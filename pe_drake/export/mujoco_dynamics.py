"""Torques computed by MuJoCo itself from an MJCF file: ``mj_inverse`` with the model's armature
and damping. Dry friction and joint limits are constraints that depend on MuJoCo's soft-constraint
settings, so they are switched off; :func:`mujoco_torques` adds ``frictionloss·sign(v)`` on request.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pe_drake.exceptions import ConfigError, MissingDependencyError


def import_mujoco():
    """The ``mujoco`` module; MissingDependencyError when it is not installed."""
    try:
        import mujoco  # lazy: an optional dependency
    except ImportError as err:
        raise MissingDependencyError("mujoco", "a MuJoCo model (pe_drake[mujoco])") from err
    return mujoco


def load_mjcf(path_or_text: str | Path, *, text: bool = False, assets: dict[str, bytes] | None = None):
    """An ``MjModel`` from an MJCF file (or its text, with its mesh files as ``assets``);
    ConfigError with MuJoCo's message when it refuses the file."""
    mujoco = import_mujoco()
    try:
        if text:
            return mujoco.MjModel.from_xml_string(str(path_or_text), assets or {})
        return mujoco.MjModel.from_xml_path(str(path_or_text))
    except (ValueError, OSError) as err:
        where = "the MJCF text" if text else f"'{path_or_text}'"
        raise ConfigError(f"MuJoCo cannot load {where}: {err}") from err


def joint_addresses(model, joint_names) -> tuple[np.ndarray, np.ndarray]:
    """(qpos addresses, dof addresses) of the named joints; ConfigError unless hinges or slides."""
    mujoco = import_mujoco()
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
    missing = [j for j in joint_names if j not in names]
    if missing:
        raise ConfigError(f"the MuJoCo model has no joint(s) {', '.join(missing)}; its joints are "
                          f"{', '.join(str(n) for n in names)}")
    qpos, dof = [], []
    for name in joint_names:
        j = model.joint(name)
        if int(j.type[0]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise ConfigError(f"MuJoCo joint '{name}' is not a hinge or slide joint")
        qpos.append(int(j.qposadr[0]))
        dof.append(int(j.dofadr[0]))
    return np.array(qpos), np.array(dof)


def mujoco_torques(model, joint_names, q: np.ndarray, v: np.ndarray, vd: np.ndarray, *,
                   sliding_friction: bool = False) -> np.ndarray:
    """Joint torques MuJoCo's ``mj_inverse`` gives at (q, v, vd) (S, n), shape (S, n) [N·m or N].

    Other joints of the model stay at their ``qpos0`` at rest; the model's options are restored.

    Args:
        joint_names: the columns of q, v, vd, length n.
        sliding_friction: add ``frictionloss·sign(v)``, the dry friction of a sliding joint.
    """
    mujoco = import_mujoco()
    qpos_adr, dof_adr = joint_addresses(model, joint_names)
    flags = model.opt.disableflags
    model.opt.disableflags = flags | int(mujoco.mjtDisableBit.mjDSBL_FRICTIONLOSS) | int(
        mujoco.mjtDisableBit.mjDSBL_LIMIT) | int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    try:
        data = mujoco.MjData(model)
        q, v, vd = np.atleast_2d(q), np.atleast_2d(v), np.atleast_2d(vd)
        out = np.empty_like(q, dtype=float)
        for s in range(q.shape[0]):
            data.qpos[:] = model.qpos0
            data.qvel[:] = 0.0
            data.qacc[:] = 0.0
            data.qpos[qpos_adr] = q[s]
            data.qvel[dof_adr] = v[s]
            data.qacc[dof_adr] = vd[s]
            mujoco.mj_inverse(model, data)
            out[s] = data.qfrc_inverse[dof_adr]
    finally:
        model.opt.disableflags = flags
    if sliding_friction:
        out = out + joint_frictionloss(model, joint_names) * np.sign(v)
    return out


def joint_frictionloss(model, joint_names) -> np.ndarray:
    """The ``frictionloss`` of the named joints of an MjModel, shape (n,) [N·m or N]."""
    return np.asarray(model.dof_frictionloss[joint_addresses(model, joint_names)[1]], float)
