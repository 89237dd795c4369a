"""examples/humanoid_g1_arms.py (the paper's Tables I and II on G1) in --quick mode.

One quick run (three motions of 15 IPOPT iterations each, 16 random candidates) feeds every
test. They check the files and what is true whatever the optimizer reaches: the numbers
in tables.json are those of the written trajectories, and stacking another motion's rows
under C never lowers σ_min(C) nor σ_max(C) (CᵀC only gains a positive semidefinite term,
so every singular value is non-decreasing). cond(C) = σ_max/σ_min has no such guarantee
(both grow), so it is not tested for monotonicity.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "humanoid_g1_arms.py"

pytestmark = pytest.mark.slow


def _load_example():
    spec = importlib.util.spec_from_file_location("humanoid_g1_arms", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def example():
    return _load_example()


@pytest.fixture(scope="module")
def quick_run(example, tmp_path_factory):
    out = tmp_path_factory.mktemp("g1_quick")
    code = example.main(["--quick", "--out", str(out)])
    return code, out, json.loads((out / "tables.json").read_text())


def _cond(C: np.ndarray) -> float:
    s = np.linalg.svd(C, compute_uv=False)
    return float(s[0] / s[-1])


def test_quick_run_writes_both_tables_and_the_trajectories(quick_run):
    code, out, t = quick_run
    assert code == (0 if t["success"] else 1)
    for key in ("setting", "table1", "table2", "ratio_first_motion", "timing", "files", "paper"):
        assert key in t
    s = t["setting"]
    # The paper's setting (section IV-B): N = 10, ω = π/4, T = 40 at 0.2 s, K = 400 at 0.02 s.
    assert (s["harmonics"], s["cost_samples"], s["constraint_samples"]) == (10, 40, 400)
    assert s["omega"] == pytest.approx(math.pi / 4)
    assert s["cost_sample_spacing_s"] == pytest.approx(0.2)
    assert s["constraint_sample_spacing_s"] == pytest.approx(0.02)
    assert s["balance_radius_m"] == pytest.approx(0.01)
    assert s["variables"] == 294 and len(t["joints"]) == 14
    assert t["quick"] is True and s["starts"] == 1
    for name in ("table1", "table2"):
        table = t[name]
        assert table["motion"] == [1, 2, 3]
        for key in ("cond_motion", "cond_total", "sigma_min_total", "sigma_max_total"):
            assert len(table[key]) == 3 and all(np.isfinite(table[key]))
        # After motion 1, C is that motion alone.
        assert table["cond_total"][0] == pytest.approx(table["cond_motion"][0], rel=1e-9)
    assert t["table1"]["paper_hrp4"] == {"cond_motion": [47.6, 114.2, 125.5], "cond_total": [47.6, 35.7, 33.9]}
    assert t["table2"]["paper_hrp4"] == {"cond_motion": [274.1, 332.0, 436.2], "cond_total": [274.1, 156.3, 124.7]}
    assert len(t["timing"]["wall_time_per_motion_s"]) == 3
    r = t["ratio_first_motion"]
    assert r["ratio"] == pytest.approx(t["table2"]["cond_motion"][0] / t["table1"]["cond_motion"][0])
    assert r["paper"] == pytest.approx(274.1 / 47.6)
    md = (out / "tables.md").read_text()
    assert "Table I" in md and "Table II" in md and "47.6" in md and "274.1" in md
    for f in t["files"]:
        assert (out / f).is_file()
    assert {f"baseline_{i}/trajectory.json" for i in (1, 2, 3)} <= set(t["files"])
    ok = [i for i, good in zip(t["table1"]["motion"], t["table1"]["success"]) if good]
    assert {f"motion_{i}/trajectory.json" for i in ok} <= set(t["files"])
    assert not list(out.rglob(".*.tmp")), "a temporary file was left behind"


def test_singular_values_of_the_concatenation_never_decrease(quick_run):
    _, _, t = quick_run
    for name in ("table1", "table2"):
        lo, hi = t[name]["sigma_min_total"], t[name]["sigma_max_total"]
        assert all(b >= a * (1 - 1e-12) for a, b in zip(lo, lo[1:])), (name, lo)
        assert all(b >= a * (1 - 1e-12) for a, b in zip(hi, hi[1:])), (name, hi)
        np.testing.assert_allclose(np.divide(hi, lo), t[name]["cond_total"], rtol=1e-8)


def test_greedy_baseline_picks_the_best_candidate_first(quick_run):
    _, _, t = quick_run
    t2 = t["table2"]
    assert t2["cond_motion"][0] == pytest.approx(min(p["cond_min"] for p in t2["per_amplitude"]))
    assert t2["candidates"] == sum(p["accepted"] for p in t2["per_amplitude"])


def test_tables_match_the_written_trajectories(g1, quick_run):
    """Recompute cond(C^(i)) and cond(C) from the trajectory.json files."""
    from pe_drake.config import ExcitationConfig
    from pe_drake.excitation.problem import ExcitationProblem
    from pe_drake.excitation.trajectory_file import load_trajectory

    _, out, t = quick_run
    s = t["setting"]
    problem = ExcitationProblem(
        g1,
        ExcitationConfig(
            harmonics=s["harmonics"],
            omega=s["omega"],
            cost_samples=s["cost_samples"],
            constraint_samples=s["constraint_samples"],
        ),
    )
    for name, folder in (("table1", "motion"), ("table2", "baseline")):
        table = t[name]
        if name == "table1" and not all(table["success"]):
            continue  # failed motions are in C but have no trajectory file
        blocks = []
        for i in table["motion"]:
            trajectory, data = load_trajectory(out / f"{folder}_{i}" / "trajectory.json")
            assert data["joints"] == t["joints"]
            blocks.append(problem.regressor_block(trajectory.alpha))
            assert table["cond_motion"][i - 1] == pytest.approx(_cond(blocks[-1]), rel=1e-6)
            assert table["cond_total"][i - 1] == pytest.approx(_cond(np.vstack(blocks)), rel=1e-6)
            assert data["cond"] == pytest.approx(table["cond_total"][i - 1], rel=1e-9)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--motions", "0"], "positive integer"),
        (["--starts", "two"], "positive integer"),
        (["--candidates", "1", "--baseline-amplitudes", "0.1"], "cannot supply 3 baseline motions"),
        (["--baseline-amplitudes", "0.1", "-0.2"], "positive number"),
        (["--baseline-amplitudes", "0.1", "0.1"], "must differ"),
        (["--max-time", "nan"], "number >= 0"),
        (["--criterion", "trace"], "invalid choice"),
        (["--config", "/nonexistent/g1.yaml"], "does not exist"),
    ],
)
def test_bad_arguments_exit_with_a_message(example, capsys, argv, match):
    with pytest.raises(SystemExit) as info:
        example.main(argv + ["--out", "/tmp/unused_g1_tables"])
    assert info.value.code == 2
    assert match in capsys.readouterr().err


def test_a_bad_config_value_is_reported(example, tmp_path, capsys):
    config = tmp_path / "bad.yaml"
    config.write_text("excitation: {harmonics: 0}\n")
    assert example.main(["--config", str(config), "--out", str(tmp_path / "out")]) == 2
    assert "excitation.harmonics must be a positive integer" in capsys.readouterr().err
    assert not (tmp_path / "out" / "tables.json").exists()
