"""The re-identified base parameters against the a-priori model: payload, rigid-body report,
and the change of the base parameters that non-separable effects merge into.

The change Δφ_B = φ_B - K φ_prior has covariance C = K Σ_φ Kᵀ + Cov(φ_B) under "the
a-priori model is right to within Σ_φ" (:class:`BaseChange`). A payload is one link's 10
parameters explaining it (GLS), named when its mass change is positive, the χ² gain passes
``payload_alpha``, the mass change exceeds ``payload_min_prior_sigmas`` a-priori standard
deviations of the link's mass and 3 of its own, and what is left is consistent with the
a-priori uncertainty (:func:`payload_search`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.diagnosis.effects import Separability, chi2, chi2_quantile, fit_payload, payload_groups
from pe_drake.diagnosis.options import DiagnosisConfig
from pe_drake.diagnosis.result import NamedEffect, per_joint
from pe_drake.multibody.payload import PayloadInertia, link_columns

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True, eq=False)
class BaseChange:
    """The re-identified base parameters φ_B (b,) and their change from K φ_prior (b,).

    Attributes:
        Sigma_phi: a-priori covariance of the standard parameters, (p, p).
        C_prior: K Σ_φ Kᵀ, (b, b).
        C: C_prior + cov_B, the covariance of Δφ_B under "no change", (b, b).
    """

    phi_B: np.ndarray
    phi_B_prior: np.ndarray
    cov_B: np.ndarray
    Sigma_phi: np.ndarray
    C_prior: np.ndarray
    C: np.ndarray

    @classmethod
    def from_fit(cls, K: np.ndarray, phi_B: np.ndarray, phi_B_prior: np.ndarray, cov_B: np.ndarray,
                 Sigma_phi: np.ndarray) -> BaseChange:
        """The change of a fit's base parameters, with K the base composition (b, p)."""
        C_prior = K @ Sigma_phi @ K.T
        return cls(phi_B, phi_B_prior, cov_B, Sigma_phi, C_prior, C_prior + cov_B)

    @property
    def delta_B(self) -> np.ndarray:
        """Δφ_B = φ_B - K φ_prior, (b,)."""
        return self.phi_B - self.phi_B_prior


@dataclasses.dataclass(frozen=True, eq=False)
class PayloadOutcome:
    """The payload search: diagnosis.json's ``payload_test``, the named payload or None, and its
    10 parameter changes Δφ_L about the link origin or None."""

    report: dict[str, Any]
    effect: NamedEffect | None
    delta_phi: np.ndarray | None


@dataclasses.dataclass(frozen=True, eq=False)
class _LinkFit:
    entry: dict[str, Any]
    x: np.ndarray
    group: tuple[str, ...]
    joint: int


def payload_search(robot: Robot, base, change: BaseChange, config: DiagnosisConfig,
                   rms_held: np.ndarray) -> PayloadOutcome:
    """The payload test of the module docstring (``rms_held``: per-joint held-out RMS of the
    last fit [N·m], before and after alike: the payload is within the rigid-body step)."""
    joints = robot.joint_names
    chi2_0 = chi2(change.delta_B, change.C)
    report: dict[str, Any] = {"searched": True, "chi2_before": chi2_0, "dof": int(base.count),
                              "prior_uncertainty": config.prior_uncertainty, "links": []}
    fits = _link_fits(robot, base, change, chi2_0)
    report["links"] = [f.entry for f in fits]
    if not fits:
        report["decision"] = "no link where an added mass is identifiable"
        return PayloadOutcome(report, None, None)
    # Links whose fit is as good within χ²₁(95 %) explain the change equally well (a mass on
    # the axis of joint k moves the same whether it rides on link k or on the link before):
    # name the most distal one, where payloads are carried, and list the others.
    first_best = max(fits, key=lambda f: f.entry["gain"])  # the first of equal gains, as max gives
    tie = first_best.entry["gain"] - chi2_quantile(0.95, 1)

    equivalent = [f for f in fits if f.entry["gain"] >= tie]
    best = max(equivalent, key=lambda f: f.joint)
    entry = best.entry
    report["equivalent_links"] = [f.entry["link"] for f in equivalent if f is not best]
    gain_needed = chi2_quantile(1 - config.payload_alpha, entry["rank"])
    rest_allowed = chi2_quantile(0.999, base.count - entry["rank"])
    report.update(best_link=entry["link"], gain_needed=gain_needed, rest_allowed=rest_allowed,
                  chi2_after=entry["chi2_after"])
    reasons = _no_payload_reasons(entry, gain_needed, rest_allowed, config)
    if reasons:
        report["decision"] = "no payload: " + "; ".join(reasons)
        return PayloadOutcome(report, None, None)
    report["decision"] = f"payload on {entry['link']}"
    return PayloadOutcome(report, _payload_effect(best, report, joints, rms_held), best.x)


def _link_fits(robot: Robot, base, change: BaseChange, chi2_0: float) -> list[_LinkFit]:
    """The GLS fit of Δφ_B by each identifiable link group's parameters."""
    fits = []
    for j, lead, group in payload_groups(robot, base):
        K_L = base.K[:, link_columns(robot, lead)]  # the payload model shared with identification
        x, cov, chi2_after = fit_payload(change.delta_B, change.C, K_L)
        rank = int(np.linalg.matrix_rank(K_L, 1e-9))
        m, m_std = float(x[0]), math.sqrt(max(float(cov[0, 0]), 0.0))
        idx = [10 * k for k, name in enumerate(robot.body_names) if name in group]
        m_prior_std = math.sqrt(max(float(change.Sigma_phi[np.ix_(idx, idx)].sum()), 0.0))
        entry = {"link": robot.body_names[lead], "joint": robot.joint_names[j], "chi2_after": chi2_after,
                 "gain": chi2_0 - chi2_after, "rank": rank, "mass": m, "mass_std": m_std,
                 "mass_prior_std": m_prior_std}
        fits.append(_LinkFit(entry, x, group, j))
    return fits


def _no_payload_reasons(entry: dict[str, Any], gain_needed: float, rest_allowed: float,
                        config: DiagnosisConfig) -> list[str]:
    reasons = []
    if entry["mass"] < 0:  # the link carries less than the a-priori model: a finding, not a payload
        reasons.append(f"negative mass change {entry['mass']:+.3g} kg, not a payload (a body cannot have negative "
                       "mass): the link carries less mass than the a-priori model (a tool or hand in the model "
                       "but not on the robot?)")
    if entry["gain"] < gain_needed:
        reasons.append(f"χ² gain {entry['gain']:.3g} < {gain_needed:.3g}")
    if abs(entry["mass"]) < config.payload_min_prior_sigmas * entry["mass_prior_std"]:
        reasons.append(f"mass change {entry['mass']:+.3g} kg within {config.payload_min_prior_sigmas:g} "
                       f"a-priori σ ({entry['mass_prior_std']:.3g} kg)")
    if abs(entry["mass"]) < 3 * entry["mass_std"]:  # detection is the χ² test; this says it is a mass
        reasons.append(f"mass change {entry['mass']:+.3g} ± {entry['mass_std']:.2g} kg not significant")
    if entry["chi2_after"] > rest_allowed:
        reasons.append(f"not localized: χ² left {entry['chi2_after']:.3g} > {rest_allowed:.3g} (the "
                       "rest of the model also differs from the a-priori one)")
    return reasons


def _payload_effect(best: _LinkFit, report: dict[str, Any], joints: Sequence[str],
                    rms_held: np.ndarray) -> NamedEffect:
    entry, x = best.entry, best.x
    m = float(x[0])
    com = PayloadInertia.from_phi(x).com.tolist()  # the payload model shared with identification
    return NamedEffect(
        "payload", "", entry["link"], m, "kg", entry["mass_std"], abs(m) / max(entry["mass_std"], 1e-300),
        per_joint(joints, rms_held), per_joint(joints, rms_held),
        {"com": com, "com_unit": "m, in the link frame", "rigidly_attached": list(best.group),
         "equally_well_on": report["equivalent_links"],
         "delta_phi": x.tolist(), "chi2_before": report["chi2_before"], "chi2_after": entry["chi2_after"],
         "mass_prior_std": entry["mass_prior_std"],
         "note": "the rigid-body step already fits it; the augmented model carries it as a welded body"})


def rigid_report(base, change: BaseChange) -> dict[str, Any]:
    """The rigid-body step's base parameters against the a-priori model, largest change first."""
    sd_prior = np.sqrt(np.maximum(np.diag(change.C_prior), 0))
    sd_est = np.sqrt(np.maximum(np.diag(change.cov_B), 0))
    z = (change.phi_B - change.phi_B_prior) / np.maximum(np.sqrt(np.diag(change.C)), 1e-300)
    order = np.argsort(-np.abs(z))
    rows = [{"name": base.base_names[k], "prior": float(change.phi_B_prior[k]),
             "identified": float(change.phi_B[k]), "std": float(sd_est[k]), "prior_std": float(sd_prior[k]),
             "z_vs_prior": float(z[k])}
            for k in order]
    return {"count": base.count, "base_parameters": rows,
            "max_abs_z_vs_prior": float(np.abs(z).max()) if z.size else 0.0}


def not_separable_report(sep: Sequence[Separability], base, change: BaseChange) -> list[dict[str, Any]]:
    """The effects no motion separates from the rigid-body terms, with the change of the base
    parameters they merge into expressed as the effect's value."""
    out = []
    names = list(base.base_names)
    delta_B = change.delta_B
    for s in sep:
        if s.separable:
            continue
        c = s.candidate
        entry: dict[str, Any] = {"effect": c.effect, "joint": c.joint_name,
                                 "merged_with": s.merged_with, "unit": c.unit}
        if s.merged_with:
            # The column is Σ_k β_k (column of base parameter k): the effect's value θ moves
            # those base parameters by θ β_k. θ if the whole change were this effect: the
            # least-squares fit of Δφ_B on β over those parameters, weighted by the prior.
            idx = [names.index(name) for name in s.merged_with]
            beta = np.array(list(s.merged_with.values()))
            sd = np.sqrt(np.maximum(np.diag(change.C_prior)[idx], 1e-300))
            w = 1.0 / sd**2
            theta = float(np.sum(w * beta * delta_B[idx]) / np.sum(w * beta**2))
            theta_sd = float(1.0 / np.sqrt(np.sum(w * beta**2)))
            entry.update(base_parameter_change={n: float(delta_B[k]) for n, k in zip(s.merged_with, idx)},
                         prior_std={n: float(x) for n, x in zip(s.merged_with, sd)},
                         implied_value_if_all=theta, implied_value_prior_std=theta_sd,
                         z_vs_prior=theta / theta_sd,
                         note="only its sum with the base parameter(s) it merges with is identifiable: the "
                              "change is reported with the rigid-body step, not named as this effect")
        out.append(entry)
    return out
