"""pe_drake.excitation.sequential_study: the paper's Tables I and II as a library call.

A small G1 study (3 motions, 1 start of 15 IPOPT iterations each, 2 × 4 random candidates)
feeds every test. With one start per motion, motion i > 1 is solved from the warm start (the
earlier motion whose coefficients give the lowest criterion on the current prior; motion 2 also
from its seed's random start, since repeating motion 1 is a stationary point).
The solver returns the best feasible point it evaluated, the warm start included (it is an
earlier motion, feasible under the same constraints), and cond ≤ soft_cond, so cond(C) after
motion i can never exceed soft_cond of that warm start; for motion 2 the warm start is
motion 1 repeated, whose soft_cond is that of motion 1 alone (the criterion is scale-free).
That is what is asserted; nothing about how far the optimizer gets.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError
from pe_drake.excitation.criteria import evaluate_criterion
from pe_drake.excitation.sequential_study import StudyOptions, run_sequential_study

OPTIONS = StudyOptions(
    motions=3, starts=1, workers=1, max_iterations=15, candidates=4, baseline_amplitudes=(0.05, 0.1), quick=True
)


@pytest.fixture(scope="module")
def study():
    return run_sequential_study(OPTIONS)


def _cond(C: np.ndarray) -> float:
    s = np.linalg.svd(C, compute_uv=False)
    return float(s[0] / s[-1])


def _soft(C: np.ndarray) -> float:
    return evaluate_criterion(C, "soft_cond", gradient=False).value


def test_the_tables_have_one_column_per_motion_and_start_at_motion_one(study):
    t = study.tables
    assert t["setting"]["motions"] == 3 and t["setting"]["starts"] == 1 and t["quick"] is True
    for name in ("table1", "table2"):
        table = t[name]
        assert table["motion"] == [1, 2, 3]
        for key in ("cond_motion", "cond_total", "sigma_min_total", "sigma_max_total"):
            assert len(table[key]) == 3 and all(np.isfinite(table[key]))
        assert table["cond_total"][0] == pytest.approx(table["cond_motion"][0], rel=1e-9)
        # Stacking rows only adds a PSD term to CᵀC: no singular value of C can fall.
        assert np.all(np.diff(table["sigma_min_total"]) >= -1e-12 * table["sigma_min_total"][0])
        assert np.all(np.diff(table["sigma_max_total"]) >= -1e-12 * table["sigma_max_total"][0])
    assert len(t["table2"]["per_amplitude"]) == 2
    assert sum(p["accepted"] for p in t["table2"]["per_amplitude"]) == t["table2"]["candidates"] == 8
    r = t["ratio_first_motion"]
    assert r["ratio"] == pytest.approx(t["table2"]["cond_motion"][0] / t["table1"]["cond_motion"][0])


def test_running_cond_values_are_those_of_the_stacked_blocks(study):
    blocks = [m.block for m in study.sequence.motions]
    t1 = study.tables["table1"]
    for i in range(1, 4):
        C = np.vstack(blocks[:i])
        assert t1["cond_total"][i - 1] == pytest.approx(_cond(C), rel=1e-9)
        assert t1["sigma_min_total"][i - 1] == pytest.approx(np.linalg.svd(C, compute_uv=False)[-1], rel=1e-9)


def test_prior_data_never_makes_c_worse_than_the_warm_start(study):
    motions = study.sequence.motions
    blocks = [m.block for m in motions]
    t1 = study.tables["table1"]
    assert study.tables["setting"]["criterion"] == "soft_cond"
    for i in range(2, 4):
        if not all(m.success for m in motions[:i]):
            continue  # an infeasible earlier motion is no feasible warm start
        prior = np.vstack(blocks[: i - 1])
        bound = min(_soft(np.vstack([prior, b])) for b in blocks[: i - 1])
        assert t1["cond_total"][i - 1] <= bound * (1 + 1e-9)
    if motions[0].success:
        assert t1["cond_total"][1] <= _soft(blocks[0]) * (1 + 1e-9)


def test_write_puts_the_tables_and_every_trajectory_in_the_folder(study, tmp_path):
    files = study.write(tmp_path / "out")
    out = tmp_path / "out"
    written = json.loads((out / "tables.json").read_text())
    assert written["files"] == files
    assert [f for f in files if f.startswith("baseline_")] == [f"baseline_{i}/trajectory.json" for i in (1, 2, 3)]
    ok = [m.index for m in study.sequence.motions if m.success]
    assert [f for f in files if f.startswith("motion_")] == [f"motion_{i}/trajectory.json" for i in ok]
    assert all((out / f).is_file() for f in files)
    md = (out / "tables.md").read_text()
    assert md == study.markdown()
    assert "Table I" in md and "Table II" in md and "(quick run)" in md
    console = study.console()
    assert "Table I" in console and "Table II" in console and "cond(C) after each motion" in console


@pytest.mark.parametrize(
    "change, match",
    [
        ({"motions": 0}, "motions must be a positive integer"),
        ({"executor": "threads"}, "executor must be 'local' or 'ray'"),
        ({"baseline_amplitudes": (0.1, -0.1)}, "baseline amplitudes must be positive"),
        ({"baseline_amplitudes": (0.1, 0.1)}, "must differ"),
        ({"candidates": 1, "baseline_amplitudes": (0.1,)}, "cannot supply 3 baseline motions"),
    ],
)
def test_bad_options_are_a_config_error_before_any_solve(change, match):
    with pytest.raises(ConfigError, match=match):
        dataclasses.replace(OPTIONS, **change)
