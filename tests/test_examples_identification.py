"""The identification examples run and print what the README shows."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_identify_panda_example(tmp_path, capsys):
    assert load("identify_panda").main(["--out", str(tmp_path), "--duration", "5"]) == 0
    out = capsys.readouterr().out
    assert "held-out RMS torque error" in out and "physical" in out
    assert (tmp_path / "model.urdf").is_file()


def test_real_panda_example(tmp_path, capsys):
    module = load("real_panda")
    if not module.DEFAULT_DATA.is_file():
        assert module.main(["--out", str(tmp_path)]) == 0
        assert "skipped" in capsys.readouterr().out
        pytest.skip("real data not present")
    assert module.main(["--out", str(tmp_path)]) == 0
    assert "a-priori URDF" in capsys.readouterr().out
    assert (tmp_path / "model.urdf").is_file() and (tmp_path / "identified.json").is_file()


def test_user_constraint_example(capsys):
    load("user_constraint").main()
    out = capsys.readouterr().out
    assert "success: True" in out
    height = float(out.split("lowest flange height over the period:")[1].split()[0])
    assert height >= 0.45 - 1e-3  # the user's table, checked at 2000 samples
