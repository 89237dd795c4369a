"""One shape for every front door (issue 33): ``door(robot: Robot, inputs, options, *,
progress=None) -> XResult``, each result with ``summary_lines() -> list[str]`` and
``write(folder, *, ...) -> list[str]`` (the paths written), and ``robot: Robot`` typed in every
signature of pe_drake that takes a robot."""

from __future__ import annotations

import ast
import importlib
import inspect
from pathlib import Path

import numpy as np
import pytest

import pe_drake
from pe_drake.identification.measurements import Measurement

PACKAGE = Path(pe_drake.__file__).parent
#: door name → its result class (the return annotation names it).
DOORS = {
    "optimize_motion": "MotionPlan",
    "read_measurements": "Measurement",
    "identify_model": "IdentifiedModel",
    "validate_model": "ValidationReport",
    "diagnose": "DiagnosisResult",
    "simulate_run": "SimulatedRun",
    "export_model": "ExportResult",
}
#: The documented exception: optimize builds its robot from the config once the collision
#: capsules are fitted to the meshes (the robot's geometry depends on them).
ROBOT_FROM_CONFIG = {"optimize_motion": "config"}
#: Modules below multibody/ (rank 0) cannot name the Robot type, even for a type checker.
BASE_LAYER = {"exceptions.py", "plots.py"}


def _door(name):
    return getattr(pe_drake, name)


def _result(name):
    door = _door(name)
    return getattr(importlib.import_module(door.__module__), DOORS[name])


@pytest.mark.parametrize("name", sorted(DOORS))
def test_every_door_has_one_shape(name):
    door = _door(name)
    params = list(inspect.signature(door).parameters.values())
    first = ROBOT_FROM_CONFIG.get(name, "robot")
    assert params[0].name == first, f"{name}: first parameter {params[0].name}, not {first}"
    if first == "robot":
        assert params[0].annotation == "Robot", f"{name}: robot annotated {params[0].annotation!r}"
    positional = [p for p in params if p.kind == p.POSITIONAL_OR_KEYWORD]
    assert all(p.kind in (p.KEYWORD_ONLY, p.VAR_KEYWORD) for p in params[len(positional):]), name
    # robot, inputs, options; optimize's config is both the robot and the options
    options = positional[-1] if first == "robot" else positional[0]
    assert options.name == ("options" if first == "robot" else "config"), f"{name}: no options last"
    progress = {p.name: p for p in params}.get("progress")
    assert progress is not None and progress.kind == progress.KEYWORD_ONLY and progress.default is None, \
        f"{name}: progress must be keyword-only, default None"
    assert inspect.signature(door).return_annotation == DOORS[name]


@pytest.mark.parametrize("name", sorted(DOORS))
def test_every_result_summarises_and_writes_itself_into_a_folder(name):
    cls = _result(name)
    summary = inspect.signature(cls.summary_lines)
    assert list(summary.parameters) == ["self"] and summary.return_annotation == "list[str]", name
    write = inspect.signature(cls.write)
    params = list(write.parameters.values())
    assert [p.name for p in params[:2]] == ["self", "folder"], f"{name}.write({', '.join(p.name for p in params)})"
    assert all(p.kind == p.KEYWORD_ONLY and p.default is not p.empty for p in params[2:]), \
        f"{name}.write: options after the folder are keyword-only with defaults"
    assert write.return_annotation == "list[str]", f"{name}.write returns {write.return_annotation}"


def test_every_door_is_a_name_of_the_package():
    assert set(DOORS) <= set(pe_drake.__all__)


def test_every_robot_parameter_is_typed():
    untyped = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name in BASE_LAYER and path.parent == PACKAGE:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = node.args
                untyped += [f"{path.relative_to(PACKAGE.parent)}:{arg.lineno} {node.name}"
                            for arg in a.posonlyargs + a.args + a.kwonlyargs
                            if arg.arg == "robot" and arg.annotation is None]
    assert not untyped, f"robot parameters without a type: {untyped}"


def test_a_measurement_writes_what_it_was_read_from(tmp_path, panda):
    t = np.arange(40) / 100.0
    q = panda.nominal_posture() + np.linspace(0.0, 0.1, 40)[:, None]
    m = Measurement(t, q, np.zeros_like(q), joints=panda.joint_names, source="lab.csv")
    written = m.write(tmp_path / "out")
    assert written == [str(tmp_path / "out" / "measurement.csv")]
    again = pe_drake.read_measurements(panda, written[0])
    np.testing.assert_allclose(again.q, q)
    assert again.summary_lines()[0] == f"data {written[0]}: 40 samples, 0.39 s at 100 Hz"


def test_diagnose_writes_itself_as_the_cli_writes_it(panda, tmp_path, capsys):
    """The CLI face no longer stages the diagnosis's folder: DiagnosisResult.write does, and
    names the joints as the model does (report.md cut 'panda_' off)."""
    from pe_drake.cli import main
    from pe_drake.excitation.trajectory_file import load_trajectory
    from pe_drake.identification.measurements import write_measurement_csv
    from pe_drake.simulation.synthetic import model_measurement

    trajectory = load_trajectory(Path(__file__).parent / "data" / "diagnosis_panda_trajectory.json")[0]
    m = model_measurement(panda, trajectory, rate_hz=500.0, duration=12.0, tau_noise_std=0.05, seed=1)
    csv = tmp_path / "a.csv"
    write_measurement_csv(csv, m.replace(v=None, vd=None, source=str(csv)))
    assert main(["diagnose", "--robot", "panda", "--data", str(csv), "--out", str(tmp_path / "cli")]) == 0
    printed = capsys.readouterr().out
    result = pe_drake.diagnose(panda, pe_drake.read_measurements(panda, csv))
    written = result.write(tmp_path / "lib")
    assert "wrote " + ", ".join(str(tmp_path / "cli" / Path(p).name) for p in written) in printed
    assert sorted(Path(p).name for p in written) == sorted(p.name for p in (tmp_path / "cli").iterdir())
    assert all(Path(p).is_file() for p in written)
    assert "| panda_joint1 |" in (tmp_path / "lib" / "report.md").read_text()
    assert result.summary_lines()[0].startswith("a-priori model, held-out RMS: panda_joint1 ")


def test_a_result_written_to_a_file_name_is_refused_with_the_call_to_make(tmp_path):
    """write(folder, name=...): ``run.write("held.csv")`` would have made a folder held.csv."""
    from pe_drake.exceptions import ConfigError

    m = Measurement(t=np.arange(3) * 0.01, q=np.zeros((3, 1)), tau=np.zeros((3, 1)), joints=("j",))
    with pytest.raises(ConfigError, match=r"write\('.*', name='held.csv'\)"):
        m.write(tmp_path / "held.csv")
    assert not (tmp_path / "held.csv").exists()
    assert m.write(tmp_path, name="held.csv") == [str(tmp_path / "held.csv")]


def test_simulate_run_names_its_options_type_when_given_a_truth_path(panda, tmp_path):
    """simulate_run(robot, trajectory, truth_path) was the shape before the one door shape."""
    with pytest.raises(TypeError, match=r"SimulateOptions\(truth"):
        pe_drake.simulate_run(panda, tmp_path / "trajectory.json", tmp_path / "truth.yaml")
