"""The diagnosis examples run and print what the README shows."""

from __future__ import annotations

import pytest

from tests.test_examples_identification import load


def test_diagnose_simulated_example(tmp_path, capsys):
    assert load("diagnose_simulated").main(["--out", str(tmp_path), "--duration", "12"]) == 0
    out = capsys.readouterr().out
    assert "coulomb_friction" in out or "viscous_friction" in out, out
    assert (tmp_path / "diagnosis.json").is_file() or any(tmp_path.rglob("diagnosis.json"))


def test_diagnose_real_panda_example(tmp_path, capsys):
    module = load("diagnose_real_panda")
    if not module.DEFAULT_DATA.is_file():
        assert module.main(["--out", str(tmp_path)]) == 0
        assert "skip" in capsys.readouterr().out.lower()
        pytest.skip("real data not present")
    assert module.main(["--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "coulomb_friction" in out
    assert any(tmp_path.rglob("diagnosis.json"))
