"""The random-candidate baseline of reference [16]: rejection sampling and greedy selection."""

from __future__ import annotations

import itertools
import math
import multiprocessing

import numpy as np
import pytest

from pe_drake.config import ExcitationConfig
from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.baseline import (
    BaselineOptions,
    RandomMotion,
    generate_candidates,
    greedy_select,
    random_baseline,
)
from pe_drake.excitation.constraints import constraints_from_config
from pe_drake.excitation.constraints.base import state_margins
from pe_drake.excitation.problem import ExcitationProblem

# Panda with capsule self-collision over a 10 s period: a quarter of the draws collide.
CONFIG = ExcitationConfig(
    harmonics=3,
    omega=2 * math.pi / 10,
    cost_samples=12,
    constraint_samples=40,
    amplitude=0.6,
    collision_margin=0.01,
)


def _synthetic_blocks(seed: int = 0, count: int = 7, rows: int = 6, cols: int = 4) -> list[np.ndarray]:
    """Random blocks with column scales spread over two decades, so cond differs a lot."""
    rng = np.random.default_rng(seed)
    return [rng.normal(size=(rows, cols)) * rng.uniform(0.1, 10.0, cols) for _ in range(count)]


def _brute_force_greedy(blocks, motions, C0=None):
    """The rule of the paper's baseline, evaluated on the full stacked matrices."""
    chosen, totals = [], []
    for _ in range(motions):
        scores = {}
        for k in range(len(blocks)):
            if k in chosen:
                continue
            parts = ([C0] if C0 is not None else []) + [blocks[j] for j in chosen] + [blocks[k]]
            scores[k] = np.linalg.cond(np.vstack(parts))
        best = min(scores, key=lambda k: (scores[k], k))
        chosen.append(best)
        totals.append(scores[best])
    return chosen, totals


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_greedy_selection_matches_brute_force(seed):
    blocks = _synthetic_blocks(seed)
    selection = greedy_select(blocks, 3)
    chosen, totals = _brute_force_greedy(blocks, 3)
    assert selection.indices == chosen
    np.testing.assert_allclose(selection.cond_total, totals, rtol=1e-9)
    np.testing.assert_allclose(selection.cond_each, [np.linalg.cond(blocks[k]) for k in chosen], rtol=1e-9)
    # The first pick is the lowest cond alone, and cond(C) after it is that same number.
    alone = [np.linalg.cond(b) for b in blocks]
    assert selection.indices[0] == int(np.argmin(alone))
    assert selection.cond_total[0] == pytest.approx(min(alone))
    # Greedy is a heuristic: never better than the best subset of the same size.
    best_subset = min(
        np.linalg.cond(np.vstack([blocks[k] for k in s])) for s in itertools.combinations(range(7), 3)
    )
    assert selection.cond_total[-1] >= best_subset - 1e-9


def test_greedy_selection_with_prior_data_and_r_factors():
    blocks = _synthetic_blocks(5)
    C0 = _synthetic_blocks(6, count=1)[0]
    selection = greedy_select(blocks, 2, C0=C0)
    chosen, totals = _brute_force_greedy(blocks, 2, C0)
    assert selection.indices == chosen
    np.testing.assert_allclose(selection.cond_total, totals, rtol=1e-9)
    # Short blocks are used as they are; tall ones through their R factor: same answer.
    tall = [np.vstack([b, b[::-1]]) for b in blocks]
    assert greedy_select(tall, 3).indices == _brute_force_greedy(tall, 3)[0]


def test_greedy_selection_refuses_bad_input():
    blocks = _synthetic_blocks()
    with pytest.raises(ConfigError, match="cannot select"):
        greedy_select(blocks[:2], 3)
    with pytest.raises(ConfigError, match="positive"):
        greedy_select(blocks, 0)
    with pytest.raises(ConfigError, match="columns"):
        greedy_select([blocks[0], blocks[1][:, :3]], 1)


@pytest.fixture(scope="module")
def candidates(panda):
    return generate_candidates(panda, CONFIG, 6, seed=100, workers=1)


def test_rejection_sampling_keeps_only_feasible_draws(panda, candidates):
    problem = ExcitationProblem(panda, CONFIG)
    constraints = constraints_from_config(panda, CONFIG)

    def sample_margins(problem, alpha):
        states = problem.constraint_basis.evaluate_alpha(np.asarray(alpha, float), problem.n)
        return state_margins(panda.limits, constraints, *states)

    assert [c.name for c in constraints] == ["collision"]
    assert len(candidates.candidates) == 6
    assert candidates.rejected.get("collision", 0) > 0, "the test needs some rejected draws"
    assert candidates.draws == 6 + sum(candidates.rejected.values())
    kept = {c.seed for c in candidates.candidates}
    for d in range(candidates.draws):
        seed = 100 + d
        alpha = problem.initial_guess(seed, CONFIG.amplitude)
        margins = sample_margins(problem, alpha)
        if seed in kept:
            assert min(margins.values()) >= 0, margins
        else:
            assert min(margins.values()) < 0, margins  # rejected for a reason
    for c in candidates.candidates:
        assert isinstance(c, RandomMotion)
        np.testing.assert_array_equal(c.alpha, problem.initial_guess(c.seed, CONFIG.amplitude))
        assert c.margins == pytest.approx(sample_margins(problem, c.alpha))
        assert c.cond == pytest.approx(np.linalg.cond(problem.regressor_block(c.alpha)), rel=1e-9)
    # R factors stand for the blocks in cond of any concatenation.
    blocks = [problem.regressor_block(c.alpha) for c in candidates.candidates[:3]]
    stacked = np.linalg.cond(np.vstack(list(candidates.R[:3])))
    assert stacked == pytest.approx(np.linalg.cond(np.vstack(blocks)), rel=1e-8)


def test_candidates_do_not_depend_on_the_worker_count(panda, candidates):
    parallel = generate_candidates(panda, CONFIG, 6, seed=100, workers=2)
    assert parallel.workers == 2
    assert [c.seed for c in parallel.candidates] == [c.seed for c in candidates.candidates]
    assert parallel.draws == candidates.draws and parallel.rejected == candidates.rejected
    np.testing.assert_allclose(parallel.R, candidates.R, rtol=1e-12, atol=1e-12)
    assert not multiprocessing.active_children()


def test_random_baseline_selects_from_its_candidates(panda):
    events = []
    result = random_baseline(panda, CONFIG, BaselineOptions(motions=2, candidates=6, seed=100), progress=events.append)
    blocks = list(result.candidate_set.R)
    assert result.selection == greedy_select(blocks, 2)
    assert [c.seed for c in result.selected] == [
        result.candidate_set.candidates[k].seed for k in result.selection.indices
    ]
    assert events and events[-1].accepted >= 6 and str(events[-1])
    assert result.wall_time >= result.generation_time > 0


def test_too_few_feasible_draws_is_an_infeasible_error(panda):
    with pytest.raises(InfeasibleError, match="random draws met every constraint"):
        generate_candidates(panda, CONFIG, 5, seed=0, max_draws=3, workers=1)
    with pytest.raises(ConfigError, match="amplitude"):
        generate_candidates(panda, CONFIG, 5, amplitude=-1.0, workers=1)
    with pytest.raises(ConfigError, match="cannot supply"):
        random_baseline(panda, CONFIG, BaselineOptions(motions=3, candidates=2))
