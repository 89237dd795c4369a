"""Holding torque at rest: the friction a stopped joint keeps, which no friction curve predicts.

At v = 0 friction takes whatever value in [−F_s, F_s] holds the joint, which depends on how it
stopped; the Dahl state z (:mod:`pe_drake.multibody.dahl`) freezes when the joint stops, so the
candidate ``holding_torque`` is the column h(t) = m(t) · z(t; :data:`HOLDING_DISPLACEMENT`),
m the joint's rest mask, both at the full rate, their product filtered like the torque
(:func:`holding_column`). Its value H ≥ 0 [N·m] is a lower bound on the static friction. It is
a candidate only on joints with :data:`MIN_REST_PERIODS` rests in the training data. The
method is in the README's "Diagnosing a model".
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from pe_drake.diagnosis.effects import Candidate, Separability
from pe_drake.identification.rest import MIN_REST_S, REST_FLOOR, count_runs, min_rest_s, rest_mask
from pe_drake.multibody.dahl import dahl_state

if TYPE_CHECKING:  # the type only: no import at run time (cost, cycles)
    from pe_drake.multibody.robot import Robot

HOLDING = "holding_torque"
#: A joint is at rest where its filtered |v| is below this [rad/s or m/s] (identify's floor).
REST_VELOCITY = REST_FLOOR
#: Rests a joint needs in the training data to be a candidate: with one stop, any drift of that
#: window could pass for a holding torque.
MIN_REST_PERIODS = 2
#: x_p of the Dahl state of the column [rad]: a stop after sliding over more than a few x_p
#: leaves z = ±1 whatever x_p is, and a smaller one follows encoder jitter at rest.
HOLDING_DISPLACEMENT = 0.002


def record_rest_mask(record, joint: int) -> np.ndarray:
    """A joint's rest mask at a record's full rate, (T,)."""
    return rest_mask(record.v[:, joint], record.rate_hz, REST_VELOCITY, min_rest_s(record.cutoff_hz))


def segment_rests(seg, joint: int) -> np.ndarray:
    """A joint's rest mask at a segment's samples, (S,)."""
    return record_rest_mask(seg.record, joint)[seg.idx]


def holding_column(seg, joint: int, x_p: float = HOLDING_DISPLACEMENT) -> np.ndarray:
    """The holding column m·z(q; x_p) of one joint at a segment's samples, (S,): rest mask and
    Dahl state at the record's full rate, their product filtered like the torque."""
    record = seg.record
    z = dahl_state(record.q[:, joint], x_p)
    return record.filtered(record_rest_mask(record, joint) * z)[seg.idx]


def holding_candidates(robot: Robot, training) -> list[Candidate]:
    """The ``holding_torque`` candidates: one per joint with :data:`MIN_REST_PERIODS` rests or
    more in the training part (the column of a joint that never stops is zero)."""
    out = []
    for j, info in enumerate(robot.joints):
        if count_runs(segment_rests(training, j)) >= MIN_REST_PERIODS:
            out.append(Candidate(HOLDING, j, info.name, "N·m" if info.kind == "revolute" else "N", True))
    return out


def holding_separability(robot: Robot, training) -> list[Separability]:
    """:func:`holding_candidates` as separable: a column of the history is no rigid-body column."""
    return [Separability(c, 1.0, True, {}) for c in holding_candidates(robot, training)]


def holding_torque(columns, fit, library) -> np.ndarray:
    """The named holding torques H·h of a segment, (S, n) [N·m]: what the augmented model adds
    to Drake's torque (Drake's joints have no friction state at rest)."""
    out = np.zeros(columns.y.shape)
    for col in fit.columns:
        c = library.cand_of.get(col)
        if c is not None and c.effect == HOLDING:
            joint, values = columns.overrides[col]
            out[:, joint] += fit.value(col) * values
    return out


def holding_report(training, held, library, pre, effects: Sequence, joints: Sequence[str]) -> dict[str, Any]:
    """The ``holding_test`` of diagnosis.json: per joint, its rests in both parts and, for the
    candidates, the held-out RMS at rest without and with the holding torque."""
    regression, final = pre.regression, pre.final
    named = {f"{e.effect}[{e.joint}]" for e in effects}
    rows = []
    for j, name in enumerate(joints):
        tr, ho = segment_rests(training, j), segment_rests(held, j)
        col = library.col_of.get(f"{HOLDING}[{name}]")
        row = {"joint": name, "rest_periods_training": count_runs(tr),
               "rest_time_training_s": float(tr.mean() * training.duration) if tr.size else 0.0,
               "rest_periods_held_out": count_runs(ho),
               "rest_time_held_out_s": float(ho.mean() * held.duration) if ho.size else 0.0,
               "candidate": col is not None, "named": f"{HOLDING}[{name}]" in named}
        if col is None:
            row["reason"] = f"{row['rest_periods_training']} rests in the training data (< {MIN_REST_PERIODS})"
        elif np.any(ho):
            without = regression.fit([c for c in final.columns if c >= regression.num_base and c != col])
            row["heldout_rms_at_rest_before"] = _rms_at(regression.residual("held-out", without)[:, j], ho)
            row["heldout_rms_at_rest_after"] = _rms_at(regression.residual("held-out", final)[:, j], ho)
        rows.append(row)
    return {"rest_velocity": REST_VELOCITY, "min_rest_s": MIN_REST_S, "min_rest_periods": MIN_REST_PERIODS,
            "displacement": HOLDING_DISPLACEMENT, "joints": rows}


def holding_note(report: dict[str, Any]) -> str | None:
    """A progress line when no joint rests in the training data (None otherwise)."""
    rows = report["joints"]
    if any(r["candidate"] for r in rows):
        return None
    held = [f"{r['joint']} {r['rest_periods_held_out']} ({r['rest_time_held_out_s']:.3g} s)"
            for r in rows if r["rest_periods_held_out"]]
    extra = (f"; the held-out data has some ({', '.join(held)}): a training run with stops would "
             "identify it") if held else ""
    return (f"3. {HOLDING}: no joint rests in the training data (|v| < {REST_VELOCITY:.3g} rad/s for "
            f"≥ {MIN_REST_S:g} s, {MIN_REST_PERIODS} times), not tested{extra}")


def _rms_at(r: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r[mask] ** 2)))
