"""Samples at rest in identify (issue 36): a stopped joint holds a friction that tanh(v/v_s)
reads as zero; kept in the fit it biases the gravity parameters. Simulated runs with stops
whose friction is a Dahl model (z frozen at the sign of the last motion while the joint
rests), identified through the command's whole path (filter, Coulomb columns, WLS)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pe_drake.cli import main as cli
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.multibody.dahl import dahl_state
from pe_drake.identification.measurements import Measurement, write_measurement_csv
from pe_drake.identification.rest import NOISE_SIGMAS, REST_FLOOR, encoder_noise, rest_velocity
from pe_drake.simulation.synthetic import model_measurement
from pe_drake.multibody.regressor import RegressorModel
from tests.conftest import get_robot
from tests.test_identification import OPTIMIZED

RATE = 500.0  # [Hz]
COUNTS = 524288  # encoder counts per revolution (19 bit)
NOISE = 0.05  # [N·m]
RAMP = 0.4  # [s] to stop and to start again


def window(t, start, length):
    """1 during [start, start + length], smooth (sin²) ramps of RAMP before and after, 0 elsewhere;
    and its time derivative."""
    w, dw = np.zeros_like(t), np.zeros_like(t)
    for a, sign in ((start - RAMP, 1.0), (start + length, -1.0)):
        x = np.clip((t - a) / RAMP, 0, 1)
        w += sign * np.sin(0.5 * np.pi * x) ** 2
        dw += sign * ((x > 0) & (x < 1)) * 0.5 * np.pi / RAMP * np.sin(np.pi * x)
    return w, dw


def run(robot, trajectory, stops, duration, seed, friction):
    """The trajectory slowed to a stop of each (start, length) [s], 19-bit encoders, torque noise,
    friction F_c·z (Dahl state, x_p 0.02 mrad: in sliding as tanh(v/v_s)) + viscous·v; the v.* and vdot.* columns left out."""
    t = np.arange(0.0, duration, 1.0 / RATE)
    w, dw = np.zeros_like(t), np.zeros_like(t)
    for start, length in stops:
        a, b = window(t, start, length)
        w, dw = w + a, dw + b
    s_dot = 1.0 - w
    s = np.concatenate([[0.0], np.cumsum(0.5 * (s_dot[1:] + s_dot[:-1]) / RATE)])
    q, qs, qss = trajectory.evaluate(s)
    v, vd = qs * s_dot[:, None], qss * s_dot[:, None] ** 2 - qs * dw[:, None]
    tau = RegressorModel(robot)(q, v, vd) @ robot.phi_model
    tau += friction["coulomb"] * dahl_state(q, 2e-5) + friction["viscous"] * v
    tau += np.random.default_rng(seed).normal(0, NOISE, tau.shape)
    step = 2 * np.pi / COUNTS
    return Measurement(t, np.round(q / step) * step, tau, None, None, robot.joint_names)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """a.csv: 20 s with three 1.4 s stops; b.csv: another 20 s of the motion, without stops."""
    robot = get_robot("panda")
    trajectory, _ = load_trajectory(OPTIMIZED)
    friction = {"coulomb": np.array([1.5, 2.0, 1.2, 1.5, 0.8, 0.8, 0.5]), "viscous": np.full(robot.n, 0.3)}
    folder = tmp_path_factory.mktemp("rest")
    write_measurement_csv(folder / "a.csv", run(robot, trajectory, [(3.0, 1.4), (9.0, 1.4), (18.0, 1.4)], 20.0, 0,
                                                friction))
    write_measurement_csv(folder / "b.csv", run(robot, trajectory, [], 20.0, 1, friction))
    return folder


def heldout(folder, name, rest, capsys):
    out = folder / name
    assert cli(["identify", "--robot", "panda", "--data", str(folder / "a.csv"), "--rest", rest, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert cli(["validate", "--robot", "panda", "--model", str(out / "identified.json"), "--data",
                str(folder / "b.csv"), "--json", str(out / "v.json")]) == 0
    rms = np.array(list(json.loads((out / "v.json").read_text())["rms"].values()))
    return text, json.loads((out / "identified.json").read_text())["rest"], rms


def test_rest_is_kept_out_when_cross_validation_says_so(runs, capsys):
    """auto keeps the stops out (cross-validation), says so, and predicts the other run better
    than keeping them: the held friction had gone into the gravity parameters."""
    text, rest, auto = heldout(runs, "auto", "auto", capsys)
    assert rest["handling"] == "excluded" and rest["reason"].startswith("cross-validation")
    # the three stops, less what the filter's spread of the motion takes from their edges
    assert all(0.8 * 3 * 1.4 < s < 3 * 1.4 + 0.5 for s in rest["seconds"].values()), rest["seconds"]
    assert "rest: samples at rest" in text and "kept out of the fit: cross-validation" in text
    _, kept_rest, kept = heldout(runs, "keep", "keep", capsys)
    assert kept_rest["handling"] == "kept"
    print("held-out RMS kept", kept.round(4), "auto", auto.round(4))
    assert np.sqrt(np.mean(auto**2)) < 0.8 * np.sqrt(np.mean(kept**2))
    assert np.all(auto < kept + 0.01), (auto, kept)


def test_a_run_without_rests_is_fitted_as_before(runs, capsys):
    out = runs / "b_id"
    assert cli(["identify", "--robot", "panda", "--data", str(runs / "b.csv"), "--out", str(out)]) == 0
    rest = json.loads((out / "identified.json").read_text())["rest"]
    assert rest["handling"] == "none" and rest["cv_rms_kept"] is None
    assert "rest: no joint rests" in capsys.readouterr().out


def test_rest_threshold_follows_the_encoder_noise():
    """A coarse encoder's noise, filtered and differentiated, sets the threshold above the floor;
    a fine one leaves the floor."""
    robot = get_robot("panda")
    trajectory, _ = load_trajectory(OPTIMIZED)
    exact = model_measurement(robot, trajectory, rate_hz=RATE)
    for counts in (4096, COUNTS):
        step = 2 * np.pi / counts
        raw = exact.replace(q=np.round(exact.q / step) * step, v=None, vd=None)
        assert encoder_noise(raw) == pytest.approx(np.full(robot.n, step / np.sqrt(12)), rel=0.35)
        from pe_drake.identification.intake import prepare_measurement

        data = prepare_measurement(robot, raw, cutoff_hz=4.0)
        fc, fs = data.preprocessing.cutoff_hz, RATE
        want = NOISE_SIGMAS * step / np.sqrt(12) * 2 * np.pi * fc * np.sqrt(2 * fc / (3 * fs))
        got = rest_velocity(raw, data)
        assert np.allclose(got, max(want, REST_FLOOR), rtol=0.35), (counts, got, want)
