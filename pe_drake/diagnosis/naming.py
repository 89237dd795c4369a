"""The named effects of the diagnosis (step 3 of :mod:`pe_drake.diagnosis.workflow`): each
selected column as a :class:`~pe_drake.diagnosis.result.NamedEffect`, the cumulative held-out
table, and the candidates not named."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.diagnosis.effects import EXPOSING_REGIME
from pe_drake.diagnosis.options import TIMING, DiagnosisConfig
from pe_drake.diagnosis.regression import Fit, Library, Regression, Selection
from pe_drake.diagnosis.result import NamedEffect, per_joint, time_delay_effect
from pe_drake.diagnosis.selection import rejected_list

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot


@dataclasses.dataclass(frozen=True, eq=False)
class Naming:
    """The named per-joint effects and what the selection left out.

    Attributes:
        effect_cols: the model's columns: the starting fit's drive terms kept and not named,
            then the named ones (``time_delay`` included), in selection order.
        cumulative: [(step label, per-joint held-out RMS)] nominal → rigid → each effect.
        last_fit: the fit with every named effect (the last cumulative step).
        series: held-out residual of each effect's joint without it and with all named.
    """

    effect_cols: list[int]
    cumulative: list[tuple[str, np.ndarray]]
    last_fit: Fit
    effects: list[NamedEffect]
    series: list[dict[str, Any]]
    rejected: list[dict[str, Any]]


def name_effects(robot: Robot, reg: Regression, library: Library, sel: Selection, rigid: Fit, nominal_rms: np.ndarray,
                 config: DiagnosisConfig) -> Naming:
    """The cumulative table, each selected effect as a NamedEffect, the rejected candidates.

    The starting fit's drive terms kept but not named (``sel.unnamed``) enter the cumulative
    table as one step after the rigid-body fit; every named effect is added on top of them.
    """
    cumulative = [("nominal", nominal_rms), ("rigid", rigid.rms_held)]
    unnamed = list(sel.unnamed)
    named_cols = [c for c in sel.order if c not in sel.unnamed]
    fits_cum = [rigid]
    if unnamed:
        fits_cum = [reg.fit(unnamed)]
        what = "drive terms of the starting fit" + (" and terms the cross-validation keeps" if sel.kept_cv else "")
        cumulative.append((f"+ {len(unnamed)} {what}, not named", fits_cum[0].rms_held))
    for k in range(len(named_cols)):
        f = reg.fit(unnamed + named_cols[: k + 1])
        fits_cum.append(f)
        cumulative.append((f"+ {library.label(named_cols[k])}", f.rms_held))
    effects, series = _named(reg, library, sel.final, named_cols, fits_cum, robot, config, unnamed)
    return Naming(unnamed + named_cols, cumulative, fits_cum[-1], effects, series, rejected_list(reg, library, sel))


def _named(reg: Regression, library: Library, final: Fit, effect_cols: list[int], fits_cum: list[Fit], robot: Robot,
           config: DiagnosisConfig, unnamed: list[int]) -> tuple[list[NamedEffect], list[dict[str, Any]]]:
    """Each effect with its value, and the residual without it (``unnamed`` in) for its plot."""
    joints = robot.joint_names
    named: list[NamedEffect] = []
    series: list[dict[str, Any]] = []
    res_final = reg.residual("held-out", reg.fit(unnamed + effect_cols))
    for k, col in enumerate(effect_cols):
        without = reg.fit(unnamed + [x for x in effect_cols if x != col])
        value, std = final.value(col), final.std(col)

        if col == library.timing_col:
            named.append(time_delay_effect(value, std, per_joint(joints, reg.contribution_rms("held-out", final, col)),
                                           per_joint(joints, fits_cum[k].rms_held),
                                           per_joint(joints, fits_cum[k + 1].rms_held)))
            j = int(np.argmax(fits_cum[k].rms_held - fits_cum[k + 1].rms_held))
            series.append({"label": TIMING, "effect": TIMING, "joint": j, "regime": EXPOSING_REGIME[TIMING],
                           "before": reg.residual("held-out", without)[:, j], "after": res_final[:, j]})
            continue
        c = library.cand_of[col]
        details: dict[str, Any] = {"contribution_rms": float(reg.contribution_rms("held-out", final, col)[c.joint])}
        # The value is what the model file lacks (the fit starts from its friction, -c.lower): the total.
        if c.effect == "viscous_friction":
            details.update(model_file_damping=-c.lower, total=float(value - c.lower))
        if c.effect == "coulomb_friction":
            details.update(velocity_scale=config.coulomb_velocity_scale, model_file_friction=-c.lower,
                           total=float(value - c.lower))
        named.append(NamedEffect(
            c.effect, c.joint_name, "", float(value), c.unit, float(std), float(abs(value) / max(std, 1e-300)),
            per_joint(joints, fits_cum[k].rms_held), per_joint(joints, fits_cum[k + 1].rms_held), details))
        series.append({"label": c.label, "effect": c.effect, "joint": c.joint,
                       "regime": EXPOSING_REGIME[c.effect],
                       "before": reg.residual("held-out", without)[:, c.joint], "after": res_final[:, c.joint]})
    return named, series
