"""Every candidate's decision with its statistics (diagnosis.json's ``decisions``).

One entry per candidate the diagnosis considered: each per-joint effect of the library, the
timing column, the pre-sliding test of each joint and the payload search. ``decision`` is
``selected``, ``rejected``, ``kept, not named`` (:data:`~pe_drake.diagnosis.options.KEPT`),
``not separable`` or ``not tried``; ``test`` names the criterion that decided a rejection
(``sign``, ``z``, ``gain``, ``other_joints``, ``relevance`` of criteria (a)-(d); ``backward``,
``replaced`` by pre-sliding friction, ``separability``, ``presliding``, ``payload``).
``selection_rms_before``/``_after`` are the cross-validated RMS of its joint without and with
it; the statistics are those of the trial that decided it (a selected one's ``z`` from the final
fit).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pe_drake.diagnosis.effects import Separability
from pe_drake.diagnosis.options import KEPT, TIMING
from pe_drake.diagnosis.presliding import PRESLIDING, PreslidingStep
from pe_drake.diagnosis.regression import Library, Selection

#: The statistics of a :class:`~pe_drake.diagnosis.regression.Verdict` copied into an entry,
#: under the names diagnosis.json uses.
_STATS = {"z": "z", "z_min": "z_min", "value": "value", "std": "std", "rms_before": "selection_rms_before",
          "rms_after": "selection_rms_after", "relative_gain": "relative_gain", "explained_rms": "explained_rms",
          "relevance": "relevance"}


def decision_list(library: Library, sep: Sequence[Separability], sel: Selection, pre: PreslidingStep,
                  payload_test: dict[str, Any], timing_check: bool) -> list[dict[str, Any]]:
    """The ``decisions`` of the module docstring, per-joint effects in the library's order."""
    out: list[dict[str, Any]] = []
    gain_min = sel.thresholds.min_heldout_gain
    for s in sep:
        c = s.candidate
        entry: dict[str, Any] = {"effect": c.effect, "joint": c.joint_name, "unit": c.unit}
        if not s.separable:
            entry.update(decision="not separable", test="separability",
                         reason="merges with " + ", ".join(s.merged_with) if s.merged_with else "not separable")
            out.append(entry)
            continue
        out.append(_tried(entry, library.col_of[c.label], sel, pre, gain_min))
    entry = {"effect": TIMING, "joint": "", "unit": "s"}
    out.append(_tried(entry, library.timing_col, sel, pre, gain_min) if timing_check
               else {**entry, "decision": "not tried", "test": "", "reason": "timing_check is off"})
    for r in pre.report:
        out.append({"effect": PRESLIDING, "joint": r["joint"], "unit": "N·m",
                    "decision": "selected" if r["named"] else "rejected", "test": "" if r["named"] else "presliding",
                    "reason": r["reason"], "value": r["coulomb"], "statistic": r["statistic"],
                    "threshold": r["threshold"], "presliding_displacement": r["displacement"],
                    "selection_rms_before": r["selection_rms_before"],
                    "selection_rms_after": r["selection_rms_presliding"], "min_gain": gain_min})
    if payload_test.get("searched"):
        named = str(payload_test.get("decision", "")).startswith("payload on")
        entry = {"effect": "payload", "link": payload_test.get("best_link", ""), "unit": "kg",
                 "decision": "selected" if named else "rejected", "test": "" if named else "payload",
                 "reason": "" if named else payload_test.get("decision", "")}
        best = next((x for x in payload_test.get("links", []) if x["link"] == entry["link"]), None)
        if best is not None:
            entry.update(value=best["mass"], std=best["mass_std"], statistic=best["gain"],
                         threshold=payload_test.get("gain_needed"))
        out.append(entry)
    return out


def _tried(entry: dict[str, Any], col: int, sel: Selection, pre: PreslidingStep, gain_min: float) -> dict[str, Any]:
    """A library column's entry from its verdict in the selection."""
    verdict = sel.verdicts.get(col)
    if verdict is None:  # the forward selection stopped (max_effects) before trying it
        return {**entry, "decision": "not tried", "test": "", "reason": "max_effects reached"}
    entry.update({name: verdict.stats[key] for key, name in _STATS.items() if key in verdict.stats})
    entry["min_gain"] = gain_min
    if col in sel.selected and col in pre.dropped:
        entry.update(decision="rejected", test="replaced",
                     reason=f"selected, then dropped: {PRESLIDING} of its joint took its place")
    elif col in sel.unnamed:  # the starting fit's term: in the model, not named (start.start_terms)
        entry.update(decision=KEPT, test=verdict.test, reason=verdict.reason, value=sel.final.value(col),
                     std=sel.final.std(col))
    elif col in sel.selected:
        entry.update(decision="selected", test="", reason="")
        value, std = sel.final.value(col), sel.final.std(col)
        entry.update(value=value, std=std, z=abs(value) / max(std, 1e-300))
    else:
        entry.update(decision="rejected", test=verdict.test, reason=verdict.reason)
    return entry
