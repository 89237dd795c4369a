"""Does the residual of a fit look like a coupled drive the model lacks (issue 36)?

A motor that turns two joints (a coupled wrist: θ_m = R q with R_ij ≠ 0 off the diagonal) puts
its friction and rotor inertia on both: the joints' torques hold R_ij R_ik F_v q̇_k and
R_ij R_ik I_m q̈_k on row j (and the mirror on row k), and the motor's Coulomb friction
F_c tanh(θ̇_m / v_s) on both rows. Per-joint drive terms cannot hold any of it, so a fit without
the ``robot.transmission`` leaves it in the residual (on the coupled wrist of issue 36, joints 5
and 6 came out 7x and 3.5x worse than the authors' model, with no word). :func:`coupled_pairs`
fits, per pair of joints the model does not couple, these columns to the pair's residual:

- the symmetric viscous and inertial couplings (row j: q̇_k, q̈_k; row k: q̇_j, q̈_j), exact for
  any ratios;
- a shared motor's Coulomb friction tanh((q̇_j ± q̇_k)/v_s) on each row, exact for the common
  differential wrist whose motor turns both joints by the same ratio (Stäubli, many KUKA and
  ABB wrists); other ratios are covered in part.

A pair is named when these explain more than :data:`COUPLING_SHARE_WARNING` of the residual
energy of *each* of its two joints: a shared motor shows on both, while a large residual of one
joint alone (the Panda's joint 1 held out) can be fitted in part by the other joint's columns
and pooled energy would name it (56 % for Panda joints 1-6, joint 6 made worse). By chance, c
columns explain about c·τ̄/rows of white noise (τ̄ the autocorrelation time of the filtered
residual): ~14 % on the Panda's 5.5 s held-out part, a few percent on a training run.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pe_drake.multibody.drive_columns import coulomb_column

#: A pair of joints is named when the coupling columns explain more than this fraction of the
#: residual energy of each of the two: then most of what the fit leaves on both is a coupled drive.
COUPLING_SHARE_WARNING = 0.5


class CoupledPair(NamedTuple):
    """Two joints whose residual looks coupled.

    Attributes:
        joints: the two joint names.
        share: the smaller of the two joints' fractions of residual energy the coupling columns explain.
        rms: their residual RMS [N·m], shape (2,); rms_after: with the coupling columns.
    """

    joints: tuple[str, str]
    share: float
    rms: np.ndarray
    rms_after: np.ndarray


def coupled_pairs(joints, v: np.ndarray, vd: np.ndarray, residual: np.ndarray, velocity_scale: float,
                  coupled=None) -> list[CoupledPair]:
    """The pairs of joints whose residual a coupled drive explains (module docstring), largest
    share first.

    Args:
        joints: the joint names, length n.
        v, vd: joint velocities and accelerations, (S, n) [rad/s, rad/s²].
        residual: measured − predicted joint torques, (S, n) [N·m].
        velocity_scale: v_s of the Coulomb columns [rad/s].
        coupled: the transmission R the fit has (its coupled pairs are not tested), or None.
    """
    n = len(joints)
    out = []
    for j in range(n):
        for k in range(j + 1, n):
            if coupled is not None and np.any((coupled[:, j] != 0) & (coupled[:, k] != 0)):
                continue
            e = np.concatenate([residual[:, j], residual[:, k]])
            before = float(e @ e)
            if before <= 0:
                continue
            zero = np.zeros(v.shape[0])
            plus = coulomb_column(v[:, j] + v[:, k], velocity_scale)
            minus = coulomb_column(v[:, j] - v[:, k], velocity_scale)
            A = np.column_stack([
                np.concatenate([v[:, k], v[:, j]]), np.concatenate([vd[:, k], vd[:, j]]),
                np.concatenate([plus, zero]), np.concatenate([zero, plus]),
                np.concatenate([minus, zero]), np.concatenate([zero, minus])])
            x, *_ = np.linalg.lstsq(A, e, rcond=None)
            r = e - A @ x
            S = v.shape[0]
            rms = np.sqrt([np.mean(residual[:, j] ** 2), np.mean(residual[:, k] ** 2)])
            after = np.sqrt([np.mean(r[:S] ** 2), np.mean(r[S:] ** 2)])
            share = float(np.min(1.0 - after**2 / np.maximum(rms**2, 1e-300)))
            if share > COUPLING_SHARE_WARNING:
                out.append(CoupledPair((joints[j], joints[k]), share, rms, after))
    return sorted(out, key=lambda p: -p.share)


def coupling_warnings(pairs: list[CoupledPair]) -> list[str]:
    """A warning naming the pairs of :func:`coupled_pairs`, or none."""
    if not pairs:
        return []
    named = "; ".join(f"{a}-{b}: ≥ {100 * p.share:.0f} % of each one's residual energy (RMS {p.rms[0]:.3g}/{p.rms[1]:.3g} → "
                      f"{p.rms_after[0]:.3g}/{p.rms_after[1]:.3g} N·m)" for p in pairs[:3] for a, b in [p.joints])
    return [f"warning: the residual looks like a coupled drive the model lacks (a motor turning two joints): {named}"
            + (" …" if len(pairs) > 3 else "") + ". The fit is worse than it should be on these joints: give "
            "robot.transmission (ratios and coupling) in the config, and the drive terms are fitted per motor"]
