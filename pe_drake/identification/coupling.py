"""Does the residual of a fit look like a coupled drive the model lacks?

A motor that turns two joints (θ_m = R q with R_ij ≠ 0 off the diagonal) puts its friction and
rotor inertia on both, which per-joint drive terms cannot hold. :func:`coupled_pairs` fits, per
pair of joints the model does not couple, to the pair's residual: the symmetric viscous and
inertial couplings (row j: q̇_k, q̈_k; row k: q̇_j, q̈_j), exact for any ratios, and a shared
motor's Coulomb friction tanh((q̇_j ± q̇_k)/v_s) on each row, exact for a differential wrist
whose motor turns both joints by the same ratio.

A pair is named when these explain more than :data:`COUPLING_SHARE_WARNING` of the residual
energy of *each* of its joints: a shared motor shows on both, while pooled energy would name a
pair for one joint's large residual alone. By chance, c columns explain about c·τ̄/rows of
white noise (τ̄ the residual's autocorrelation time).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from pe_drake.multibody.drive_columns import coulomb_column

#: A pair is named when the coupling columns explain more than this fraction of each joint's
#: residual energy.
COUPLING_SHARE_WARNING = 0.5


class CoupledPair(NamedTuple):
    """Two joints whose residual looks coupled.

    ``share``: the smaller of the two joints' fractions of residual energy the coupling columns
    explain; ``rms``, ``rms_after``: their residual RMS [N·m], (2,), without and with them.
    """

    joints: tuple[str, str]
    share: float
    rms: np.ndarray
    rms_after: np.ndarray


def coupled_pairs(joints, v: np.ndarray, vd: np.ndarray, residual: np.ndarray, velocity_scale: float,
                  coupled=None) -> list[CoupledPair]:
    """The pairs of joints whose residual a coupled drive explains, largest share first.

    Args:
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
