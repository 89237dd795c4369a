"""The diagnosis's smallest effect and its false alarms (issue 13).

A constant offset of 0.1 N·m on every joint in 14 s of data with 0.05 N·m torque noise must
be named on every joint; clean runs with the same noise and 5 % inertial errors must name
nothing. The false-alarm rate over 20 clean runs is measured by
``python -m pe_drake.bench sensitivity`` (CI runs two seeds here).
"""

from __future__ import annotations

import pytest

from pe_drake.diagnosis.workflow import diagnose
from pe_drake.simulation.simulation import simulate
from pe_drake.simulation.truth import NoiseTruth, make_truth
from tests.test_diagnosis import CONTROL, DURATION

NOISE = NoiseTruth(encoder_counts_per_rev=524288, tau_std=0.05)


def test_small_offsets_on_every_joint_are_named(panda, diagnosis_trajectory):
    truth = make_truth(panda, {"torque_offset": {"all": 0.1}}, seed=100, inertia_perturbation=0.05, noise=NOISE,
                       control=CONTROL)
    measurement, _ = simulate(panda, diagnosis_trajectory, truth, DURATION)
    result = diagnose(panda, measurement)
    offsets = {e.joint: e.value for e in result.effects if e.effect == "torque_offset"}
    assert set(offsets) == set(panda.joint_names), offsets
    for joint, value in offsets.items():
        assert abs(value - 0.1) <= 0.01, (joint, value)
    assert {e.effect for e in result.effects} == {"torque_offset"}


@pytest.mark.parametrize("seed", [101, 102])
def test_clean_runs_name_nothing(panda, diagnosis_trajectory, seed):
    truth = make_truth(panda, seed=seed, inertia_perturbation=0.05, noise=NOISE, control=CONTROL)
    measurement, _ = simulate(panda, diagnosis_trajectory, truth, DURATION)
    result = diagnose(panda, measurement)
    assert result.effects == [], [(e.effect, e.joint) for e in result.effects]
