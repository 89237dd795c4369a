"""One library entry point per command: the library does what the CLI does, once.

- ``optimize_motion`` builds one excitation problem in this process (one per worker beside);
- ``diagnose`` filters each file once (the sign check runs on its own filtered record);
- ``optimize_motion(...).write`` gives the files ``pe-drake optimize`` gives, byte for byte;
- ``identify_model`` / ``diagnose`` on a sign-flipped log raise the DataError the CLI prints.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pe_drake.cli import main
from pe_drake.config import load_config
from pe_drake.exceptions import DataError
from pe_drake.excitation import optimize_motion
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.trajectory_file import load_trajectory
from pe_drake.identification import IdentifyOptions, identify_model
from pe_drake.identification.measurements import write_measurement_csv
from pe_drake.identification.lowpass import LowPassFilter
from pe_drake.multibody import resolve_robot_config
from pe_drake.simulation.synthetic import model_measurement
from pe_drake.viewer import write_plan_playback

DATA = Path(__file__).parent / "data"
#: report.json fields that record time or the process, not the result.
TIMING = {"solve_time_s", "multistart_time_s", "total_time_s"}


def _small_config(tmp_path):
    """The Panda demo, shortened: 25 iterations, one start."""
    cfg = tmp_path / "small.yaml"
    cfg.write_text("solver:\n  max_iterations: 25\n")
    return cfg


def _report(path: Path) -> dict:
    report = json.loads(path.read_text())
    for key in TIMING:
        report.pop(key)
    for start in report["starts"]:
        start.pop("time_s"), start.pop("task_time_s"), start.pop("worker")
    return report


def test_library_writes_what_the_cli_writes(tmp_path, monkeypatch):
    """Fails without the front door: no library call gave the ramps, the goal and the report."""
    cfg = _small_config(tmp_path)
    assert main(["optimize", "--robot", "panda", "--config", str(cfg), "--out", str(tmp_path / "cli")]) == 0
    built = []
    original = ExcitationProblem.__init__
    monkeypatch.setattr(ExcitationProblem, "__init__", lambda self, *a, **k: (built.append(1), original(self, *a, **k))[1])
    plan = optimize_motion(resolve_robot_config("panda", cfg), name="panda")
    assert len(built) == 1, f"{len(built)} excitation problems built for one in-process start"
    written = plan.write(tmp_path / "lib", playback=write_plan_playback)
    assert [Path(p).name for p in written] == sorted(p.name for p in (tmp_path / "cli").iterdir())
    for name in ("trajectory.json", "trajectory.csv", "trajectory.png", "trajectory_goal.yaml", "playback.html"):
        assert (tmp_path / "lib" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    assert _report(tmp_path / "lib" / "report.json") == _report(tmp_path / "cli" / "report.json")
    assert plan.report.cond == pytest.approx(json.loads((tmp_path / "cli" / "report.json").read_text())["cond"])


def test_the_callers_config_is_not_changed(tmp_path):
    config = resolve_robot_config("panda", _small_config(tmp_path))
    before = repr(config)
    optimize_motion(config, name="panda")
    assert repr(config) == before


@pytest.fixture(scope="module")
def runs(panda, tmp_path_factory):
    """Two simulated Panda runs (training and validation) and one with joint 2's torque negated."""
    trajectory = load_trajectory(DATA / "diagnosis_panda_trajectory.json")[0]
    folder = tmp_path_factory.mktemp("runs")
    out = {}
    for name, seed in (("a", 1), ("b", 2)):
        m = model_measurement(panda, trajectory, rate_hz=500.0, duration=12.0, tau_noise_std=0.05, seed=seed)
        out[name] = folder / f"{name}.csv"
        write_measurement_csv(out[name], m.replace(v=None, vd=None, source=str(out[name])))
        if name == "a":
            tau = m.tau.copy()
            tau[:, 1] *= -1
            out["flipped"] = folder / "flipped.csv"
            write_measurement_csv(out["flipped"], m.replace(tau=tau, v=None, vd=None, source=str(out["flipped"])))
    return out


def test_diagnose_filters_each_file_once(runs, tmp_path, monkeypatch):
    """Fails on the old CLI: it filtered each file a second time only for the sign check. The
    filters of the Coulomb column's velocity (:func:`friction_velocity`: its noise probes and its
    own, wider cut-off) are another signal's, not counted."""
    import inspect

    designed = []
    original = LowPassFilter.__init__

    def counted(self, *a, **k):
        if not any(f.function == "friction_velocity" for f in inspect.stack(0)[1:]):
            designed.append(1)
        original(self, *a, **k)

    monkeypatch.setattr(LowPassFilter, "__init__", counted)
    code = main(["diagnose", "--robot", "panda", "--data", str(runs["a"]), "--validation", str(runs["b"]),
                 "--out", str(tmp_path / "diag")])
    assert code == 0 and len(designed) == 2, f"{len(designed)} filters designed for two files"


def test_sign_flip_is_refused_by_the_library_as_by_the_cli(panda, runs, tmp_path, capsys):
    from pe_drake.diagnosis import diagnose
    from pe_drake.identification import read_measurements

    raw = read_measurements(panda, runs["flipped"])
    with pytest.raises(DataError) as by_identify:
        identify_model(panda, raw, IdentifyOptions())
    with pytest.raises(DataError) as by_diagnose:
        diagnose(panda, raw)
    for err in (by_identify.value, by_diagnose.value):
        assert "tau.panda_joint2" in str(err) and "sign-flipped" in str(err)
    assert main(["identify", "--robot", "panda", "--data", str(runs["flipped"]), "--out", str(tmp_path / "i")]) == 2
    assert str(by_identify.value) in capsys.readouterr().err
    assert main(["diagnose", "--robot", "panda", "--data", str(runs["flipped"]), "--out", str(tmp_path / "d")]) == 2
    assert str(by_diagnose.value) in capsys.readouterr().err


def test_identify_options_come_from_the_config(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("identification:\n  drive_terms: friction\ndata:\n  max_gap_s: 0.05\n")
    options = IdentifyOptions.from_config(load_config(cfg, base=resolve_robot_config("panda")), method="wls")
    assert (options.method, options.drive.terms, options.max_gap_s) == ("wls", "friction", 0.05)


def test_trajectory_files_have_size_and_harmonic_limits(tmp_path):
    """A 10⁶-harmonic file asked for 15-18 GiB of bases; a huge file was read whole."""
    from pe_drake import limits

    MAX_HARMONICS = int(limits.value(limits.HARMONICS))

    data = json.loads((DATA / "panda_optimized.json").read_text())
    n = len(data["joints"])
    data["a"] = data["b"] = [[0.0] * (MAX_HARMONICS + 1)] * n
    data["harmonics"] = MAX_HARMONICS + 1
    wide = tmp_path / "wide.json"
    wide.write_text(json.dumps(data))
    with pytest.raises(DataError, match=f"{MAX_HARMONICS + 1} harmonics; at most {MAX_HARMONICS}"):
        load_trajectory(wide)
    big = tmp_path / "big.json"
    with big.open("wb") as f:
        f.truncate(51 * 1024 * 1024)
    with pytest.raises(DataError, match=r"51\.0 MB is more than a trajectory file holds: over the 50 MB limit "
                                        r"\(PE_DRAKE_MAX_TRAJECTORY_MB raises it\)"):
        load_trajectory(big)


def test_ipopt_options_are_data_of_the_solver_config(tmp_path):
    """Solver options pass through the call (the config), not a module global the bench mutated."""
    from pe_drake.excitation import solve as solve_module
    from pe_drake.excitation.solve import option_value

    assert not hasattr(solve_module, "IPOPT_EXTRA_OPTIONS")
    assert (option_value("6"), option_value("1e-8"), option_value("matching")) == (6, 1e-8, "matching")
    cfg = tmp_path / "s.yaml"
    cfg.write_text("solver:\n  ipopt_options: {max_soc: '4', spral_scaling: matching}\n")
    config = load_config(cfg, base=resolve_robot_config("panda"))
    assert config.solver.ipopt_options == {"max_soc": "4", "spral_scaling": "matching"}


def test_every_front_door_is_a_name_of_the_package():
    """Issue 33: the six doors are importable from `pe_drake` itself and are the stages' own."""
    import pe_drake
    from pe_drake.diagnosis import diagnose
    from pe_drake.identification import read_measurements, validate_model
    from pe_drake.simulation import simulate_run

    doors = (optimize_motion, simulate_run, read_measurements, identify_model, validate_model, diagnose)
    assert all(getattr(pe_drake, door.__name__) is door for door in doors)
    assert {d.__name__ for d in doors} <= set(pe_drake.__all__)
