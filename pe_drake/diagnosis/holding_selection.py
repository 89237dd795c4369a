"""The holding torque in the effect selection: tried together with its joint's Coulomb friction.

A joint that slides and stops carries its friction in two columns (Coulomb while it slides,
holding while it rests). The forward selection adds one column at a time, and with only one of
the two in, the other's torque stays in the residual, whose long correlated stretches inflate
every σ, so neither may pass alone. :func:`add_friction_pairs` tries the pair on each joint
where neither was named.
"""

from __future__ import annotations

import dataclasses

from pe_drake.diagnosis.holding import HOLDING
from pe_drake.diagnosis.regression import Library, Regression, Scorer, Selection, accept, integrated_autocorrelation


def add_friction_pairs(reg: Regression, split: Scorer, library: Library, sel: Selection, max_effects: int) -> Selection:
    """``sel`` with (coulomb_friction, holding_torque) of every joint where neither was
    selected and both pass :func:`~pe_drake.diagnosis.regression.accept` together (each
    against the fit without the pair), at most ``max_effects`` in all; updates ``reg``'s
    autocorrelation inflation like the forward selection does."""
    selected, order, rejected, steps = list(sel.selected), list(sel.order), dict(sel.rejected), list(sel.steps)
    verdicts = dict(sel.verdicts)
    current, current_split = sel.final, split.fit(list(sel.selected))
    for hold, cand in library.cand_of.items():
        if cand.effect != HOLDING or hold in selected:
            continue
        coulomb = library.col_of.get(f"coulomb_friction[{cand.joint_name}]")
        if coulomb is None or coulomb in selected or len(selected) + 2 > max_effects + (library.timing_col in selected):
            continue
        fit, trial = reg.fit(selected + [coulomb, hold]), split.fit(selected + [coulomb, hold])
        pair = {col: accept(col, fit, trial, current_split, library, sel.thresholds) for col in (coulomb, hold)}
        if not all(v.accepted for v in pair.values()):
            reason = "; ".join(v.reason for v in pair.values() if not v.accepted)
            rejected[hold] = f"{rejected.get(hold, '')}; with coulomb_friction[{cand.joint_name}]: {reason}".lstrip("; ")
            failed = pair[hold] if not pair[hold].accepted else pair[coulomb]
            verdicts[hold] = failed._replace(reason=rejected[hold])  # decisions and rejected say the same
            continue
        for col in (coulomb, hold):
            selected.append(col)
            order.append(col)
            rejected.pop(col, None)
            verdicts[col] = pair[col]
            steps.append(("+", col, fit))
        current, current_split = fit, trial
        reg.inflation = integrated_autocorrelation(reg.residual("training", current))
    if current is sel.final:
        return dataclasses.replace(sel, rejected=rejected, verdicts=verdicts)
    return dataclasses.replace(sel, selected=selected, order=order, final=reg.fit(selected), rejected=rejected,
                               steps=steps, verdicts=verdicts)
