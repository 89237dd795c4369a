"""Sequential generation (section IV-B) and multi-start.

Small problems on the Panda (N = 3, a 1 s period, few samples and iterations): these tests
check the mechanics (what C0 each motion sees, which start is kept, what the processes do),
not the quality of the optimum. The executors themselves are tested in test_parallel.py.
"""

from __future__ import annotations

import math
import multiprocessing

import numpy as np
import pytest

from pe_drake.config import ExcitationConfig, SolverConfig
from pe_drake.exceptions import ConfigError, NoSolutionFound
from pe_drake.excitation.constraints.base import SampledConstraint, SampledValues
from pe_drake.excitation.multistart import MultiStartOptions, StartEvent, WorkerError, best_index, solve_multistart
from pe_drake.excitation.parallel import ExecutorOptions, open_executor
from pe_drake.excitation.problem import ExcitationProblem
from pe_drake.excitation.sequential import MotionEvent, SequenceOptions, motion_seeds, optimize_sequence

CONFIG = ExcitationConfig(
    harmonics=3,
    omega=2 * math.pi,  # 1 s period: the 1 kHz re-check of the result has 1000 samples
    cost_samples=12,
    constraint_samples=40,
    criterion="log_cond",
    amplitude=0.3,
)
SOLVER = SolverConfig(max_iterations=8, verbose=False)
ONE_WORKER = ExecutorOptions(workers=1)


def no_constraints(robot, config):
    return []


class _Unreachable(SampledConstraint):
    """q_1 >= 100 rad: no trajectory satisfies it."""

    name = "unreachable"

    def __init__(self, n: int):
        self.n = n
        super().__init__(["q1"], [100.0], [np.inf])

    def evaluate(self, q, v, vd, derivatives=True):
        d_q = np.zeros((q.shape[0], 1, self.n))
        d_q[:, 0, 0] = 1.0
        return SampledValues(value=q[:, :1], d_q=d_q)


def unreachable_constraints(robot, config):
    return [_Unreachable(robot.n)]


def failing_constraints(robot, config):
    raise ConfigError("constraint factory failed on purpose")


def _cond(C):
    return float(np.linalg.cond(C))


@pytest.fixture(scope="module")
def sequence(panda):
    events = []
    options = SequenceOptions(motions=3, starts=1, constraints_factory=no_constraints, run=ONE_WORKER,
                              warm_start=False)  # every start at its seed's random point (see the warm-start test)
    result = optimize_sequence(panda, CONFIG, SOLVER, options, progress=events.append)
    return result, events


def test_each_motion_is_optimized_on_the_stacked_earlier_blocks(panda, sequence):
    result, _ = sequence
    problem = ExcitationProblem(panda, CONFIG, base=result.base)
    blocks = [problem.regressor_block(m.result.x) for m in result.motions]
    for i, m in enumerate(result.motions):
        np.testing.assert_allclose(m.block, blocks[i], rtol=1e-12, atol=1e-12)
        stacked = np.vstack(blocks[: i + 1])
        # cond of [C^(1); ...; C^(i)] computed here, and the solver's own cond(C), which it
        # computed with its C0: they agree only if C0 was exactly the earlier blocks.
        assert m.cond_total == pytest.approx(_cond(stacked), rel=1e-9)
        assert m.result.cond == pytest.approx(_cond(stacked), rel=1e-9)
        assert m.cond_motion == pytest.approx(_cond(blocks[i]), rel=1e-9)
        assert m.result.cond_motion == pytest.approx(m.cond_motion, rel=1e-9)
    np.testing.assert_allclose(result.C, np.vstack(blocks), rtol=1e-12, atol=1e-12)
    assert result.cond == pytest.approx(result.motions[-1].cond_total)


def test_each_motion_starts_from_its_own_seed(panda, sequence):
    result, events = sequence
    assert [m.seeds for m in result.motions] == [motion_seeds(CONFIG.seed, i, 1) for i in (1, 2, 3)]
    assert len({m.seed for m in result.motions}) == 3
    starts = [e for e in events if isinstance(e, StartEvent) and e.kind == "started"]
    assert [(e.label, e.seed) for e in starts] == [
        (f"motion {i}", m.seed) for i, m in zip((1, 2, 3), result.motions)
    ]
    finished = [e for e in events if isinstance(e, MotionEvent) and e.kind == "finished"]
    assert [e.motion for e in finished] == result.motions
    assert all(str(e) for e in events)


def test_prior_data_is_the_first_block_of_C(panda, sequence):
    first, _ = sequence
    C0 = first.motions[0].block
    result = optimize_sequence(panda, CONFIG, SOLVER, SequenceOptions(
        motions=1, seed=first.motions[1].seed, C0=C0, constraints_factory=no_constraints, run=ONE_WORKER))
    # Same prior, same seed, same solver: motion 2 of the first run again.
    np.testing.assert_allclose(result.motions[0].result.x, first.motions[1].result.x, rtol=0, atol=1e-10)
    np.testing.assert_allclose(result.C[: len(C0)], C0)
    assert result.cond == pytest.approx(first.motions[1].cond_total, rel=1e-9)


def test_warm_start_begins_at_the_best_earlier_motion(panda):
    events = []
    result = optimize_sequence(panda, CONFIG, SOLVER, SequenceOptions(
        motions=3, starts=2, constraints_factory=no_constraints, run=ONE_WORKER), progress=events.append)
    started = [e for e in events if isinstance(e, StartEvent) and e.kind == "started"]
    # Motion 1: two random starts; motions 2 and 3: a random start, then the warm start.
    assert [e.origin.split(",")[0] for e in started[:2]] == ["", ""]
    m1, m2, m3 = result.motions
    assert started[3].origin.startswith("from motion 1") and started[3].seed == m2.seeds[1]
    problem = ExcitationProblem(panda, CONFIG, C0=np.vstack([m1.block, m2.block]), base=result.base)
    best = int(np.argmin([problem.value(m.result.x) for m in (m1, m2)]))
    assert started[5].origin.startswith(f"from motion {best + 1}")
    assert "from motion" in str(started[5])
    # Repeating motion 1 leaves cond unchanged (cond is scale-free), so motion 2 starts at
    # cond(C^(1)) and the solver (no constraints here) can only improve on it.
    assert _cond(np.vstack([m1.block, m1.block])) == pytest.approx(m1.cond_total, rel=1e-9)
    assert m2.cond_total <= m1.cond_total * (1 + 1e-9)


def test_a_one_start_sequence_gives_motion_2_a_random_start_beside_the_warm_start(panda):
    """Repeating motion 1 is a stationary point of the stacked criterion: a lone warm start ended
    where it began (G1 --quick: motion 2 = motion 1, cond 713.6 -> 713.6)."""
    events = []
    result = optimize_sequence(panda, CONFIG, SOLVER, SequenceOptions(
        motions=3, starts=1, constraints_factory=no_constraints, run=ONE_WORKER), progress=events.append)
    started = [e for e in events if isinstance(e, StartEvent) and e.kind == "started"]
    origins = [e.origin.split(",")[0] for e in started]
    assert origins[0] == "" and origins[1] == "" and origins[2].startswith("from motion 1")  # motion 2: two
    assert len(started) == 4 and origins[3].startswith("from motion")  # motion 3: the warm start alone
    m1, m2, _ = result.motions
    assert len(m2.seeds) == 2 and m2.cond_total <= m1.cond_total * (1 + 1e-9)


def test_multistart_in_two_processes_keeps_the_best_and_equals_serial(panda):
    seeds = [3, 4, 5]
    events = []
    parallel = solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions(
        seeds, constraints_factory=no_constraints, run=ExecutorOptions(workers=2)), progress=events.append)
    serial = solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions(
        seeds, constraints_factory=no_constraints, run=ONE_WORKER))
    assert parallel.workers == 2 and parallel.executor == "local"
    assert serial.workers == 1 and serial.executor == "main"
    for a, b in zip(parallel.results, serial.results):
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
        assert a.fun == pytest.approx(b.fun, rel=1e-12)
    conds = [r.cond for r in serial.results]
    assert all(r.success for r in serial.results)
    assert parallel.seed == serial.seed == seeds[int(np.argmin(conds))]
    assert parallel.best.cond == min(conds)
    assert [s.seed for s in parallel.starts] == seeds
    assert {(e.seed, e.kind) for e in events} >= {(s, k) for s in seeds for k in ("started", "finished")}
    assert not multiprocessing.active_children()


def test_best_index_prefers_feasible_starts():
    class R:
        def __init__(self, fun, success, cond=None):
            self.fun, self.success, self.cond = fun, success, fun if cond is None else cond

    assert best_index([R(1.0, False), R(3.0, True), R(2.0, True)]) == 2
    assert best_index([R(5.0, False), R(4.0, False)]) == 1
    assert best_index([R(2.0, True), R(2.0, True)]) == 0
    # Issue 38: the kept start has the lowest reported cond, not the lowest soft_cond (32 G1
    # starts kept soft_cond 190 at cond 182.88 while another reached cond 181.93) ...
    starts = [R(190.0, True, cond=182.88), R(191.0, True, cond=181.93)]
    assert best_index(starts) == best_index(starts, "cond") == 1
    # ... except for a criterion that is not a cond (D-optimality): the criterion itself.
    assert best_index(starts, "dopt") == 0
    assert best_index([R(float("nan"), True, cond=float("inf")), R(3.0, True)]) == 1


def test_worker_errors_reach_the_caller_and_leave_no_process(panda):
    with pytest.raises(WorkerError, match="on purpose") as info:
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions(
            [0, 1], constraints_factory=failing_constraints, run=ExecutorOptions(workers=2)))
    assert info.value.exception_type == "ConfigError" and info.value.task in (0, 1)
    assert not multiprocessing.active_children()
    # In this process (one worker) the exception itself propagates.
    with pytest.raises(ConfigError, match="on purpose"):
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions(
            [0, 1], constraints_factory=failing_constraints, run=ONE_WORKER))


def test_sequence_in_two_processes_equals_serial(panda, sequence):
    serial, _ = sequence
    with open_executor(panda, "local", 2, constraints_factory=no_constraints) as ex:
        parallel = optimize_sequence(panda, CONFIG, SOLVER, SequenceOptions(
            motions=3, warm_start=False, run=ExecutorOptions(executor=ex)))
    assert parallel.workers == 1  # one start per motion: one at a time
    for a, b in zip(parallel.motions, serial.motions):
        np.testing.assert_array_equal(a.result.x, b.result.x)
        assert a.starts[0].worker.startswith("pid ")
    assert not multiprocessing.active_children()


def test_a_motion_without_a_feasible_start_raises_with_the_partial_result(panda):
    with pytest.raises(NoSolutionFound) as info:
        optimize_sequence(panda, CONFIG, SolverConfig(max_iterations=3, verbose=False), SequenceOptions(
            motions=2, constraints_factory=unreachable_constraints, run=ONE_WORKER))
    partial = info.value.result
    assert len(partial.motions) == 1 and not partial.success
    assert partial.motions[0].result.margins["unreachable"] < 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"motions": 0}, "motions"),
        ({"starts": 0}, "starts"),
        ({"motions": 2, "seeds": [[1]]}, "seeds"),
        ({"C0": np.zeros((5, 3))}, "columns"),
    ],
)
def test_bad_arguments_are_refused(panda, kwargs, match):
    with pytest.raises(ConfigError, match=match):
        optimize_sequence(panda, CONFIG, SOLVER, SequenceOptions(constraints_factory=no_constraints, run=ONE_WORKER,
                                                                 **kwargs))


def test_multistart_refuses_bad_seeds(panda):
    with pytest.raises(ConfigError, match="differ"):
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions([1, 1], run=ONE_WORKER))
    with pytest.raises(ConfigError, match="at least one"):
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions([], run=ONE_WORKER))
    with pytest.raises(ConfigError, match="workers"):
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions([1, 2], run=ExecutorOptions(workers=0)))
    with pytest.raises(ConfigError, match="1 origins for 2 seeds"):
        solve_multistart(panda, CONFIG, SOLVER, MultiStartOptions([1, 2], origins=["from motion 1"], run=ONE_WORKER))
