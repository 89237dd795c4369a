"""Identification from the ground wrench alone on a simulated G1 (issue 14)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.estimators import identify
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.prediction import predict, predict_wrench
from pe_drake.identification.measurements import measurement_to_csv_text, read_measurement_csv
from pe_drake.simulation.simulation import simulate
from pe_drake.simulation.truth import NoiseTruth, Truth, make_truth
from tests.conftest import ground_wrench

DATA = Path(__file__).parent / "data"


def _run(g1, name: str, truth: Truth, measurement: str, duration: float):
    trajectory, _ = load_trajectory(DATA / f"g1_{name}_optimized.json")
    raw, info = simulate(g1, trajectory, truth, duration=duration, measurement=measurement)
    f0 = trajectory.omega / (2 * np.pi)
    return raw, prepare_measurement(g1, raw, fundamental_hz=f0, harmonics=trajectory.harmonics), info


def test_simulated_wrench_is_the_weld_reaction_and_round_trips_through_csv(g1, tmp_path):
    """Noise-free wrench of a short run: the model's wrench at the logged states, offset on top."""
    truth = make_truth(g1, seed=4, inertia_perturbation=0.1,
                       noise=NoiseTruth(wrench_offset=[0.1, -0.2, 3.0, 0.01, -0.02, 0.03]))
    raw, data, info = _run(g1, "base_wrench", truth, "base_wrench", 1.0)
    assert raw.tau is None and raw.wrench.shape == (raw.num_samples, 6)
    assert info["measurement"] == "base_wrench"
    path = tmp_path / "run.csv"
    path.write_text(measurement_to_csv_text(raw))
    back = read_measurement_csv(path, g1.joint_names)
    assert back.tau is None and np.allclose(back.wrench, raw.wrench, rtol=1e-9, atol=1e-9)
    # The true model predicts the filtered wrench at the filtered states (offset added).
    phi_true = np.concatenate([info["phi_true"][b] for b in g1.body_names])
    offset = np.array(truth.noise.wrench_offset)
    predicted = ground_wrench(g1, phi_true, data.q, data.v, data.vd) + offset
    # Up to the low-pass filter's and the central differences' error (measured 0.014 N, N·m;
    # the arms move the wrench by 1-3 N·m, the sensor noise is 0.5 N / 0.05 N·m).
    assert np.abs(predicted - data.wrench).max() < 0.02


@pytest.mark.slow
def test_wrench_identification_predicts_held_out_arm_torques(g1):
    """0.5 N / 0.05 N·m of F/T noise on the wrench-optimized run (one 8 s period); the arm
    torques of another run (the torque-optimized motion), which the wrench never saw, are
    predicted within 5 % of each joint's RMS."""
    truth = make_truth(g1, seed=1, inertia_perturbation=0.1, noise=NoiseTruth(force_std=0.5, moment_std=0.05))
    _, data, info = _run(g1, "base_wrench", truth, "base_wrench", 8.0)
    _, held_out, _ = _run(g1, "joint_torque", make_truth(g1, seed=1, inertia_perturbation=0.1), "both", 8.0)
    phi_true = np.concatenate([info["phi_true"][b] for b in g1.body_names])
    result = identify(g1, data, "wls", measurement="base_wrench")
    assert result.base.count == 96 and result.channels[-1] == "wrench.mz"
    truth_B = result.base.base_values(phi_true)
    assert np.linalg.norm(result.phi_B - truth_B) < 5e-3 * np.linalg.norm(truth_B)
    rms = np.sqrt(np.mean(held_out.tau**2, axis=0))
    error = np.sqrt(np.mean((predict(g1, result, held_out) - held_out.tau) ** 2, axis=0))
    assert np.all(error < 0.05 * rms), 100 * error / rms
    wrench_error = np.sqrt(np.mean((predict_wrench(g1, result, held_out) - held_out.wrench) ** 2, axis=0))
    assert np.all(wrench_error[:3] < 0.05) and np.all(wrench_error[3:] < 0.02)  # [N], [N·m]


@pytest.mark.slow
def test_cli_simulate_identify_validate_with_the_wrench(tmp_path, capsys):
    """The --measurement flags end to end on a short G1 run (mechanics, not accuracy)."""
    import json

    from pe_drake.cli import main

    traj = str(DATA / "g1_base_wrench_optimized.json")
    truth = tmp_path / "truth.yaml"
    truth.write_text("seed: 2\ninertia_perturbation: 0.1\nnoise: {force_std: 0.5, moment_std: 0.05}\n")
    run = tmp_path / "run.csv"
    assert main(["simulate", "--robot", "g1", "--trajectory", traj, "--truth", str(truth), "--out", str(run),
                 "--duration", "2", "--measurement", "base_wrench"]) == 0
    header = run.read_text().splitlines()[0].split(",")
    assert header[-6:] == ["wrench.fx", "wrench.fy", "wrench.fz", "wrench.mx", "wrench.my", "wrench.mz"]
    assert not any(c.startswith("tau.") for c in header)
    out = tmp_path / "ident"
    assert main(["identify", "--robot", "g1", "--data", str(run), "--measurement", "base_wrench", "--method", "wls",
                 "--trajectory", traj, "--out", str(out)]) == 0
    identified = json.loads((out / "identified.json").read_text())
    assert identified["measurement"] == "base_wrench" and len(identified["base_parameters"]) == 96
    assert set(identified["residual_rms"]) == {"wrench.fx", "wrench.fy", "wrench.fz", "wrench.mx", "wrench.my", "wrench.mz"}
    report = tmp_path / "validation.json"
    assert main(["validate", "--robot", "g1", "--model", str(out / "identified.json"), "--data", str(run),
                 "--measurement", "base_wrench", "--json", str(report)]) == 0
    assert json.loads(report.read_text())["model_measurement"] == "base_wrench"
    capsys.readouterr()
    # A run without torque columns cannot validate torques, nor identify from them.
    assert main(["validate", "--robot", "g1", "--model", str(out / "identified.json"), "--data", str(run)]) == 2
    assert "tau.<joint>" in capsys.readouterr().err
    assert main(["identify", "--robot", "g1", "--data", str(run), "--out", str(tmp_path / "no")]) == 2
    assert not (tmp_path / "no").exists()


@pytest.mark.slow
def test_humanoid_base_wrench_example_runs(tmp_path, capsys):
    """examples/humanoid_base_wrench.py end to end on the stored motions, short runs."""
    import importlib.util
    import json

    path = Path(__file__).resolve().parents[1] / "examples" / "humanoid_base_wrench.py"
    spec = importlib.util.spec_from_file_location("humanoid_base_wrench", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    motions = [str(DATA / "g1_base_wrench_optimized.json"), str(DATA / "g1_joint_torque_optimized.json")]
    argv = ["--trajectories", *motions, "--candidates", "2", "--duration", "2", "--out", str(tmp_path)]
    assert example.main(argv) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ratio_torque_optimized"] > 3 and summary["ratio_random_best"] > 3
    assert {"base_wrench wls", "joint_torque physical", "a-priori model"} <= set(summary["held_out"])
    assert (tmp_path / "wrench_singular_values.png").is_file() and (tmp_path / "wrench_torque_prediction.png").is_file()
    assert "held-out arm torques" in capsys.readouterr().out
