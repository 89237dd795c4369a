"""Holding torque at rest (issue 23): a simulated Panda run that stops, with Dahl friction on
one joint (its state freezes at rest, so the joint holds ±F_c where tanh(v/v_s) gives 0), names
``holding_torque`` there and its held-out residual at rest drops; the same friction on a run
that never stops tests no holding torque and says so; a clean run that stops names none."""

from __future__ import annotations

import numpy as np
import pytest

from pe_drake.diagnosis.holding import HOLDING
from pe_drake.identification.rest import count_runs, rest_mask
from pe_drake.diagnosis.workflow import diagnose
from pe_drake.simulation.simulation import simulate
from pe_drake.simulation.truth import make_truth
from tests.held_trajectory import HeldTrajectory
from tests.test_diagnosis import CONTROL, DURATION, NOISE, named

JOINT, FC, XP = "panda_joint5", 0.5, 0.001  # Dahl F_c [N·m] and x_p [rad]
DAHL = {"presliding_friction": {JOINT: FC}, "presliding_stiffness": {JOINT: FC / XP}}


def _simulate(panda, trajectory, effects):
    return simulate(panda, trajectory, make_truth(panda, effects, control=CONTROL, noise=NOISE), DURATION)[0]


def _run(panda, trajectory, effects, validation=None):
    lines: list[str] = []
    return diagnose(panda, _simulate(panda, trajectory, effects), validation, progress=lines.append), lines


def test_rest_mask_keeps_long_stills_only():
    rate = 100.0
    v = np.ones(300)
    v[50:80] = 0.0  # 0.3 s still: a rest
    v[150:155] = 0.0  # 50 ms: a reversal, not a rest
    v[200:300] = 1e-4
    m = rest_mask(v, rate, 1e-3, 0.2)
    assert m[50:80].all() and not m[150:155].any() and m[200:].all() and m.sum() == 130
    assert count_runs(m) == 2 and count_runs(np.zeros(3, bool)) == 0 and count_runs(np.ones(2, bool)) == 1


def test_holding_torque_is_named_on_a_run_that_stops(panda, diagnosis_trajectory):
    result, lines = _run(panda, HeldTrajectory(diagnosis_trajectory), DAHL)
    found = named(result)
    assert (HOLDING, JOINT) in found, [*found]
    assert {j for _, j in found} == {JOINT}, [*found]
    assert {e for e, _ in found} <= {HOLDING, "coulomb_friction", "presliding_friction"}
    hold = found[(HOLDING, JOINT)]
    assert hold.value > 0 and hold.z > 4
    # H bounds the torque held at rest, which is F_c·|z| ≤ F_c (the column's z has x_p = 2 mrad)
    assert 0.8 * FC < hold.value < 1.5 * FC, hold.value
    row = next(r for r in result.holding_test["joints"] if r["joint"] == JOINT)
    assert row["named"] and row["rest_periods_training"] >= 2 and row["rest_periods_held_out"] >= 1
    assert row["heldout_rms_at_rest_after"] < 0.2 * row["heldout_rms_at_rest_before"], row
    j = panda.joint_names.index(JOINT)
    assert result.rms_after[j] < 0.25 * result.rms_rigid[j]
    assert any(line.startswith(f"3. + {HOLDING}[{JOINT}]") for line in lines)
    assert "holding_test" in result.to_json_dict()
    # the augmented model records it; validate's reading of the file says it is not applied
    from pe_drake.identification.identified_file import read_augmented_model, unapplied_effects

    d = result.augmented.to_dict()
    assert d["holding_torque"][JOINT] == pytest.approx(hold.value)
    notes = unapplied_effects(read_augmented_model(d, panda))
    assert any(n.startswith("the model's holding torque at rest is not applied (panda_joint5") for n in notes), notes


def test_no_holding_torque_without_rests(panda, diagnosis_trajectory):
    """Training never stops, the validation run does (the issue's real run): not tested, and
    the progress says that the held-out data has rests."""
    held = _simulate(panda, HeldTrajectory(diagnosis_trajectory, every=2.0), DAHL)
    result, lines = _run(panda, diagnosis_trajectory, DAHL, validation=held)
    assert not any(e.effect == HOLDING for e in result.effects)
    found = named(result)  # dry friction: pre-sliding since the grid reaches below 2 mrad (branch panda36)
    assert {("coulomb_friction", JOINT), ("presliding_friction", JOINT)} & set(found), [*found]
    if ("presliding_friction", JOINT) in found:
        dahl = found[("presliding_friction", JOINT)]
        assert abs(dahl.value - FC) <= 0.1 * FC and 0.5 < dahl.details["presliding_displacement"] / XP < 2.0
    rows = result.holding_test["joints"]
    assert not any(r["candidate"] for r in rows) and all(r["rest_periods_training"] == 0 for r in rows)
    assert all(r["rest_periods_held_out"] >= 2 for r in rows)
    note = next(line for line in lines if f"{HOLDING}: no joint rests in the training data" in line)
    assert "the held-out data has some" in note and f"{JOINT} " in note


def test_clean_run_that_stops_names_nothing(panda, diagnosis_trajectory):
    result, _ = _run(panda, HeldTrajectory(diagnosis_trajectory), {})
    assert not result.effects, [*named(result)]
    assert all(r["candidate"] and not r["named"] for r in result.holding_test["joints"])
