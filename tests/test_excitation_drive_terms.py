"""identify's drive terms in the excitation's C (issue 23, optional part): columns, gradient,
prior data, the expected σ of each term, and refusals."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import get_robot, sampled_gradient_error

from pe_drake.config import Config, ExcitationConfig, validate_config
from pe_drake.exceptions import ConfigError
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.quality import excitation_quality
from pe_drake.multibody.drive_columns import drive_columns

CONFIG = ExcitationConfig(harmonics=5, omega=math.pi / 4, cost_samples=60)


def _problem(name, terms, **kw):
    return ExcitationProblem(get_robot(name), dataclasses.replace(CONFIG, drive_terms=terms, **kw))


def test_columns_are_identifys_drive_columns_after_the_base_regressor():
    rigid, friction, full = (_problem("panda", t) for t in ("none", "friction", "all"))
    assert (rigid.columns, friction.columns) == (rigid.base.count, rigid.base.count + 3 * 7)
    # The Panda's first two armatures merge into base parameters (drive_terms.armature_merges).
    assert full.columns == friction.columns + 5 and set(full.drive.layout.merged) == {"panda_joint1", "panda_joint2"}
    alpha = full.initial_guess(seed=1, amplitude=0.3)
    C = full.regressor_block(alpha)
    assert np.array_equal(C[:, : rigid.base.count], rigid.regressor_block(alpha))
    _, v, vd = full.cost_basis.evaluate_alpha(alpha, full.n)
    D = drive_columns(v, vd, full.drive.layout) * full.rows.scale[None, :, None]  # rows weighted by 1/σ
    assert np.allclose(C[:, rigid.base.count :], D.reshape(-1, full.drive.count))


@pytest.mark.parametrize("name,terms,criterion", [("panda", "all", "cond"), ("panda", "friction", "soft_cond"),
                                                  ("g1", "all", "cond")])
def test_gradient_with_drive_columns_matches_central_differences(name, terms, criterion):
    problem = _problem(name, terms, criterion=criterion)
    alpha = problem.initial_guess(seed=2, amplitude=0.3)
    rel, idx, numeric = sampled_gradient_error(problem, alpha, 25, np.random.default_rng(0))
    assert rel < 1e-6, f"relative error {rel:.2e}"
    # the drive part of the gradient is not zero: without it the error is large
    rigid = ExcitationProblem(problem.robot, dataclasses.replace(problem.config, drive_terms="none"))
    assert np.linalg.norm(rigid.evaluate(alpha).grad[idx] - numeric) > 1e-3 * np.linalg.norm(numeric)


def test_prior_data_has_the_drive_columns_and_a_motion_that_never_reverses_is_singular():
    problem = _problem("panda", "friction")
    alpha = problem.initial_guess(seed=3, amplitude=0.3)
    block = problem.regressor_block(alpha)
    assert np.isfinite(problem.with_prior(block).evaluate(alpha).value)
    with pytest.raises(ConfigError, match=f"needs {problem.columns} columns"):
        problem.with_prior(block[:, : problem.base.count])
    # joint 7 held still: its Coulomb column is tanh(0) = 0, C loses rank
    n, N = problem.n, problem.harmonics
    still = alpha.copy()
    for part in range(2):
        still[part * n * N + (n - 1) * N : part * n * N + n * N] = 0.0
    assert not np.isfinite(problem.value(still)) or problem.value(still) > 1e8


def test_quality_reports_each_drive_terms_expected_sigma():
    problem = _problem("panda", "all")
    alpha = problem.initial_guess(seed=4, amplitude=0.3)
    report = excitation_quality(problem, alpha, noise_std=0.05, random_motions=0)
    assert len(report.drive_std) == problem.drive.count and np.all(report.drive_std > 0)
    assert report.drive_names[0] == "coulomb[panda_joint1]" and report.drive_units[0] == "N·m"
    line = next(line for line in report.summary_lines() if "drive terms (26)" in line)
    assert [k.split("[")[0] for k in line.split(": ", 1)[1].split("; ")] == ["coulomb", "viscous", "offset", "armature"]
    d = report.to_dict()
    assert len(d["drive_term_std"]) == 26 and len(d["base_parameter_std"]) == problem.base.count
    # σ scales with the noise: the same motion at 4× the noise gives 4× the σ
    four = excitation_quality(problem, alpha, noise_std=0.2, random_motions=0)
    assert np.allclose(four.drive_std, 4 * report.drive_std)


def test_bad_choices_are_refused():
    with pytest.raises(ConfigError, match="none, friction, all"):
        validate_config(Config(excitation=ExcitationConfig(drive_terms="coulomb")))
    with pytest.raises(ConfigError, match="ground wrench"):
        validate_config(Config(excitation=ExcitationConfig(drive_terms="all", measurement="base_wrench")))


def test_optimize_cli_with_drive_terms_writes_their_sigma_and_a_prior_run_reuses_the_columns(tmp_path, capsys):
    import json

    from pe_drake.cli import main

    cfg = tmp_path / "c.yaml"
    cfg.write_text("excitation: {harmonics: 3, cost_samples: 30}\nsolver: {max_iterations: 15}\n")
    first, second = tmp_path / "first", tmp_path / "second"
    args = ["optimize", "--robot", "panda", "--config", str(cfg), "--drive-terms", "friction", "--no-html"]
    assert main(args + ["--out", str(first)]) == 0
    printed = capsys.readouterr().out
    assert "43 base parameters of the joint_torque rows and 21 drive terms (friction)" in printed
    assert "drive terms (21), largest std of each kind: coulomb[" in printed
    quality = json.loads((first / "report.json").read_text())["quality"]
    assert [d["unit"] for d in quality["drive_term_std"][:3]] == ["N·m", "N·m·s/rad", "N·m"]
    # sequential: the earlier motion's rows (base and drive columns) are C0
    assert main(args + ["--prior", str(first / "trajectory.json"), "--out", str(second)]) == 0
    assert "prior data: 1 motion(s), 210 rows" in capsys.readouterr().out


@pytest.mark.parametrize("measurement,terms", [("both", "all"), ("both", "none"), ("base_wrench", "none")])
def test_quality_with_the_ground_wrench_uses_its_rows(measurement, terms):
    """The quality figures were built from the joint-torque rows alone, whose C does not
    determine the wrench-and-torque base parameters: every σ and the prediction RMS were inf.
    C is now the measurement's rows (wrench rows weighted by the config's force/moment σ)."""
    g1 = get_robot("g1")
    problem = ExcitationProblem(g1, ExcitationConfig(measurement=measurement, drive_terms=terms))
    report = excitation_quality(problem, problem.initial_guess(seed=0, amplitude=0.3), random_motions=0)
    assert np.all(np.isfinite(report.motion.std)) and math.isfinite(report.motion.prediction_rms_total)
    assert len(report.drive_names) == problem.drive.count
