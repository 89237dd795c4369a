"""Honest figures (issue 36): `validate --no-filter` predicts the torques as recorded, and
`validate` and `diagnose` name every joint whose held-out error is worse than the a-priori
(model file) model's or than predicting zero, and by how much."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.cli import main as cli
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.identification.reference_errors import SIGNIFICANCE, shortfalls
from pe_drake.simulation.synthetic import model_measurement
from tests.conftest import get_robot
from tests.test_identification import optimized, random_trajectory  # noqa: F401  (a fixture)

NOISE = 0.05  # [N·m]
OFFSET = 3.0  # [N·m] on joint 7 in the training run only: the fit learns it, the other run lacks it


def test_shortfalls_need_a_significant_excess():
    """A model equal to the reference up to white noise is not flagged; one 30 % worse is,
    with the percentage; the a-priori reference may cover the first channels only."""
    rng = np.random.default_rng(0)
    measured = rng.normal(0, 1.0, (4000, 3))
    reference = measured + rng.normal(0, 0.1, measured.shape)
    predicted = measured + rng.normal(0, 0.1, measured.shape) * np.array([1.0, 1.3, 1.0])
    found = shortfalls(("a", "b", "c"), measured, predicted, {"a_priori": reference[:, :2], "zero": None})
    assert [(s.channel, s.reference) for s in found] == [("b", "a_priori")]
    ratio = np.sqrt(np.mean((measured - predicted)[:, 1] ** 2) / np.mean((measured - reference)[:, 1] ** 2))
    assert found[0].percent_worse == pytest.approx(100 * (ratio - 1), rel=1e-9) and found[0].z > SIGNIFICANCE
    assert f"{100 * (ratio - 1):.0f} % worse than the a-priori (model file) model" in found[0].line()
    assert shortfalls(("a",), measured[:, :1], 3 * measured[:, :1], {"zero": 0 * measured[:, :1]})[0].reference == "zero"


def write_runs(tmp_path, optimized):  # noqa: F811
    """a.csv: the model file's torques with an offset of OFFSET on joint 7; b.csv another motion
    without it; both with white noise and exact v.*, vdot.* columns."""
    robot = get_robot("panda")
    a = model_measurement(robot, optimized, rate_hz=100, tau_noise_std=NOISE, seed=0)
    tau = a.tau.copy()
    tau[:, 6] += OFFSET
    write_measurement_csv(tmp_path / "a.csv", a.replace(tau=tau))
    b = model_measurement(robot, random_trajectory(robot, optimized, seed=7), rate_hz=100, tau_noise_std=NOISE, seed=1)
    write_measurement_csv(tmp_path / "b.csv", b)
    return robot, b


def test_validate_no_filter_and_the_joints_worse_than_the_references(optimized, tmp_path, capsys):  # noqa: F811
    """The model learned joint 7's offset; on the other run its error there is OFFSET, worse than
    the model file's (the truth) and than predicting zero; the other joints are not flagged.
    With --no-filter the RMS is of the raw torques: the white noise is in it."""
    robot, b = write_runs(tmp_path, optimized)
    assert cli(["identify", "--robot", "panda", "--data", str(tmp_path / "a.csv"), "--no-filter",
                "--out", str(tmp_path / "id")]) == 0
    model = str(tmp_path / "id" / "identified.json")
    capsys.readouterr()
    assert cli(["validate", "--robot", "panda", "--model", model, "--data", str(tmp_path / "b.csv"), "--no-filter",
                "--json", str(tmp_path / "v.json")]) == 0
    text = capsys.readouterr().out
    report = json.loads((tmp_path / "v.json").read_text())
    assert report["filtered"] is False and report["samples"] == b.num_samples
    rms = np.array(list(report["rms"].values()))
    assert np.all(np.abs(rms[:6] - NOISE) < 0.2 * NOISE), rms  # the raw noise, not the filtered one
    assert rms[6] == pytest.approx(OFFSET, rel=0.02)
    worse = report["worse_than_references"]["worse"]
    assert {(w["channel"], w["reference"]) for w in worse if w["channel"] == "panda_joint7"} == {
        ("panda_joint7", "a_priori"), ("panda_joint7", "zero")}
    # the model file is the truth here: a fit is worse by its own estimation error, flagged
    # where that is significant, and said to be a few per cent
    assert all(w["percent_worse"] < 5 for w in worse if w["channel"] != "panda_joint7"), worse
    zero = next(w for w in worse if w["reference"] == "zero")
    tau7 = np.sqrt(np.mean(b.tau[:, 6] ** 2))
    assert zero["reference_rms"] == pytest.approx(tau7, rel=1e-6)
    assert zero["percent_worse"] == pytest.approx(100 * (rms[6] / tau7 - 1), rel=1e-6)
    assert "warning: panda_joint7: held-out RMS" in text and "worse than predicting zero" in text
    assert cli(["validate", "--robot", "panda", "--model", model, "--data", str(tmp_path / "b.csv"),
                "--json", str(tmp_path / "f.json")]) == 0
    filtered = np.array(list(json.loads((tmp_path / "f.json").read_text())["rms"].values()))
    assert np.all(filtered[:6] < 0.5 * NOISE), filtered  # filtering removes most of the white noise


def test_diagnose_flags_a_joint_worse_than_the_model_file(optimized, tmp_path, capsys):  # noqa: F811
    """diagnose names joint 7's torque offset on a.csv; held out on b.csv, which lacks it, the
    augmented model is worse there than the model file and than predicting zero: said and in
    diagnosis.json."""
    write_runs(tmp_path, optimized)
    out = tmp_path / "d"
    assert cli(["diagnose", "--robot", "panda", "--data", str(tmp_path / "a.csv"), "--validation",
                str(tmp_path / "b.csv"), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    worse = json.loads((out / "diagnosis.json").read_text())["worse_than_references"]["worse"]
    assert {(w["channel"], w["reference"]) for w in worse} >= {("panda_joint7", "a_priori"), ("panda_joint7", "zero")}
    assert all(w["channel"] == "panda_joint7" for w in worse), worse
    assert "warning: panda_joint7: held-out RMS" in text and "worse than predicting zero" in text
