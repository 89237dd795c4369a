"""``--window START,END``: a part of a run, cut after the whole run is filtered."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pe_drake.cli import main
from pe_drake.exceptions import ConfigError, DataError
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification.intake import prepare_measurement
from pe_drake.identification.time_window import TimeWindow
from pe_drake.multibody import load_robot
from pe_drake.simulation.synthetic import model_measurement

DATA = Path(__file__).parent / "data"
REAL = Path(__file__).resolve().parents[2] / "shared" / "datasets" / "panda_gaz2019" / "excitation_1.csv"


def test_parse_and_refusals():
    assert TimeWindow.parse(",14.7") == TimeWindow(None, 14.7)
    assert TimeWindow.parse("2,") == TimeWindow(2.0, None)
    assert TimeWindow.parse(" 1 , 3 ") == TimeWindow(1.0, 3.0)
    for bad, match in (("3", "START,END"), ("a,b", "numbers"), ("5,2", "before its end"), ("nan,", "finite")):
        with pytest.raises(ConfigError, match=match):
            TimeWindow.parse(bad)


@pytest.fixture(scope="module")
def run():
    robot = load_robot("panda")
    trajectory, _ = load_trajectory(DATA / "panda_optimized.json")
    m = model_measurement(robot, trajectory, rate_hz=1000.0, duration=12.0, tau_noise_std=0.02, seed=1)
    return robot, m.replace(v=None, vd=None)


def test_the_window_is_cut_after_filtering(run):
    """The samples kept are those of the whole run's preprocessing; a file cut at the same time
    gets the filter's edge transient at the cut instead."""
    robot, m = run
    whole = prepare_measurement(robot, m)
    part = prepare_measurement(robot, m, window=TimeWindow(None, 6.0))
    k = whole.t <= 6.0
    np.testing.assert_array_equal(part.t, whole.t[k])
    np.testing.assert_array_equal(part.vd, whole.vd[k])
    assert part.preprocessing.samples_out == k.sum() and "--window" in part.notes[-1]
    cut = prepare_measurement(robot, m.replace(t=m.t[m.t <= 6.0], q=m.q[m.t <= 6.0], tau=m.tau[m.t <= 6.0]))
    shared = np.isin(whole.t[k], cut.t)
    edge = np.abs(cut.vd[-20:] - whole.vd[k][shared][-20:]).max()
    print(f"edge transient of the cut file at its end: {edge:.3g} rad/s²")
    assert edge > 1e-2


def test_a_window_outside_the_run_names_its_span(run):
    robot, m = run
    with pytest.raises(DataError, match=r"--window 50 s to the end keeps 0 sample\(s\) of a run that spans"):
        prepare_measurement(robot, m, window=TimeWindow(50.0, None))


def test_a_window_too_short_to_fit_says_widen_it(run):
    from pe_drake.identification.estimators import identify

    robot, m = run
    short = prepare_measurement(robot, m, window=TimeWindow(2.0, 2.1))
    with pytest.raises(DataError, match="widen --window or record a longer run"):
        identify(robot, short)
    with pytest.raises(DataError, match=r"samples\): record a longer run"):  # no window: no such hint
        identify(robot, prepare_measurement(robot, m.replace(t=m.t[:300], q=m.q[:300], tau=m.tau[:300])))


def test_cli_refuses_a_bad_window(tmp_path, capsys):
    assert main(["identify", "--robot", "panda", "--data", str(tmp_path / "x.csv"), "--window", "4,2",
                 "--out", str(tmp_path / "o")]) == 2
    assert "before its end" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.skipif(not REAL.is_file(), reason="real Panda recording not available (../shared/datasets)")
def test_validate_reproduces_diagnoses_held_out_figures_on_the_real_panda(tmp_path):
    """`validate --window` of the diagnosed model on diagnose's own held-out span gives the
    held-out RMS diagnose reports (the same filtering: the whole run; the same samples)."""
    assert main(["diagnose", "--robot", "panda", "--data", str(REAL), "--held-out-fraction", "0.3",
                 "--out", str(tmp_path / "dg")]) == 0
    report = json.loads((tmp_path / "dg" / "diagnosis.json").read_text())
    held = report["data"]["held_out"]
    window = f"{held['t_start']:.6f},{held['t_end']:.6f}"
    assert main(["validate", "--robot", "panda", "--model", str(tmp_path / "dg" / "augmented_model.json"),
                 "--data", str(REAL), "--window", window, "--json", str(tmp_path / "v.json")]) == 0
    validated = json.loads((tmp_path / "v.json").read_text())
    rms = np.array([validated["rms"][j] for j in report["joints"]])
    after = np.array([report["rms_after"][j] for j in report["joints"]])
    np.testing.assert_allclose(rms, after, rtol=0.05)
