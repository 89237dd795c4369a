"""Issue 10: measured data checked against the robot and its a-priori model (file, column, row)."""

from __future__ import annotations

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.exceptions import DataError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.data_checks import check_against_model, check_raw_measurement
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.simulation.synthetic import model_measurement


@pytest.fixture(scope="module")
def run(panda):
    from pathlib import Path

    trajectory, _ = load_trajectory(Path(__file__).parent / "data" / "panda_optimized.json")
    m = model_measurement(panda, trajectory, rate_hz=500.0, tau_noise_std=0.05, seed=1)
    return m.replace(v=None, vd=None, source="run.csv")


def test_good_run_passes(panda, run):
    check_raw_measurement(panda, run)
    s = check_against_model(panda, prepare_measurement(panda, run))
    assert np.nanmin(s) > 0.5


def test_sign_flipped_torque_column_is_named(panda, run):
    tau = run.tau.copy()
    tau[:, 1] *= -1
    with pytest.raises(DataError, match=r"column 'tau.panda_joint2'.*sign-flipped"):
        check_against_model(panda, prepare_measurement(panda, run.replace(tau=tau)))


def test_positions_in_degrees_are_named(panda, run):
    q = run.q.copy()
    q[:, 3] = np.degrees(q[:, 3])
    with pytest.raises(DataError, match=r"column 'q.panda_joint4', row \d+: .*looks like degrees"):
        check_raw_measurement(panda, run.replace(q=q))


def test_time_in_milliseconds_is_named(panda, run):
    with pytest.raises(DataError, match=r"column 't'.*looks like milliseconds"):
        check_raw_measurement(panda, run.replace(t=run.t * 1000))  # 500 Hz logged in ms: steps of 2 "s"
    t = np.arange(len(run.t)) * 1.0  # 1 kHz logged in ms
    with pytest.raises(DataError, match="divide it by 1000"):
        check_raw_measurement(panda, run.replace(t=t))


def test_gap_in_time_splits_the_run_instead_of_being_refused(panda, run):
    """Issue 22: a pause no longer refuses the file; it splits the run (tests/test_logs.py)."""
    from pe_drake.identification.gaps import split_at_pauses

    t = run.t.copy()
    t[1000:] += 2.0  # a 2 s hole
    check_raw_measurement(panda, run.replace(t=t))
    segments, notes = split_at_pauses(run.replace(t=t))
    assert [s.num_samples for s in segments] == [1000, run.num_samples - 1000] and "2.002 s" in notes[-1]


def test_cli_identify_refuses_a_flipped_column(tmp_path, capsys, panda, run):
    tau = run.tau.copy()
    tau[:, 0] *= -1
    data = tmp_path / "run.csv"
    write_measurement_csv(data, run.replace(tau=tau, source=str(data)))
    out = tmp_path / "ident"
    assert main(["identify", "--robot", "panda", "--data", str(data), "--out", str(out)]) == 2
    assert "tau.panda_joint1" in capsys.readouterr().err
    assert not out.exists()


def _run_csv(tmp_path, panda, duration):
    from pathlib import Path

    trajectory, _ = load_trajectory(Path(__file__).parent / "data" / "panda_optimized.json")
    m = model_measurement(panda, trajectory, rate_hz=500.0, duration=duration, tau_noise_std=0.05, seed=2)
    path = tmp_path / f"run{duration:g}.csv"
    write_measurement_csv(path, m.replace(v=None, vd=None, source=str(path)))
    return path


@pytest.mark.slow
def test_diagnose_splits_a_10_s_run(tmp_path, capsys, panda):
    """The README's sequence: a 10 s simulated run (one period) diagnosed without --validation."""
    data = _run_csv(tmp_path, panda, 10.0)
    assert main(["diagnose", "--robot", "panda", "--data", str(data), "--out", str(tmp_path / "d")]) == 0
    assert "held-out" in capsys.readouterr().out


def test_diagnose_says_which_part_is_short_and_what_to_change(tmp_path, capsys, panda):
    data = _run_csv(tmp_path, panda, 5.0)
    assert main(["diagnose", "--robot", "panda", "--data", str(data), "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert "the held-out part is" in err and "record a run of at least" in err and "lower the held-out" not in err
    assert not (tmp_path / "d").exists()
