"""Ramp-in + N periods + ramp-out (pe_drake.excitation.ramp): rest at the ends, smooth joins,
the path's own postures, limits at 1 kHz."""

from __future__ import annotations

import types

import numpy as np
import pytest

from pe_drake.exceptions import ConfigError, InfeasibleError
from pe_drake.excitation.fourier import FourierTrajectory
from pe_drake.excitation.ramp import (
    RampedMotion,
    choose_ramp_duration,
    phase_candidates,
    ramp_margins,
    ramped_motion_from_dict,
    smootherstep,
)


def _path(n=3, N=4, omega=2 * np.pi / 5, seed=1, scale=0.3):
    rng = np.random.default_rng(seed)
    k = np.arange(1, N + 1)
    return FourierTrajectory(rng.normal(size=(n, N)) * scale / k, rng.normal(size=(n, N)) * scale / k,
                             rng.normal(size=n) * 0.1, omega)


def _limits(path, factor=1.3):
    t = np.arange(0, path.period, 1e-3)
    q, v, vd = path.evaluate(t)
    return types.SimpleNamespace(
        q_lower=q.min(0) - 0.01, q_upper=q.max(0) + 0.01,
        v_max=np.abs(v).max(0) * factor, vd_max=np.abs(vd).max(0) * factor,
    )


def test_smootherstep_derivatives_match_finite_differences():
    x = np.linspace(0.05, 0.95, 19)
    h = 1e-6
    S, s, ds, dds = smootherstep(x)
    Sp, sp, dsp, _ = smootherstep(x + h)
    Sm, sm, dsm, _ = smootherstep(x - h)
    np.testing.assert_allclose((Sp - Sm) / (2 * h), s, atol=1e-8)
    np.testing.assert_allclose((sp - sm) / (2 * h), ds, atol=1e-7)
    np.testing.assert_allclose((dsp - dsm) / (2 * h), dds, atol=1e-6)
    assert smootherstep(np.array(1.0))[0] == pytest.approx(0.5)


@pytest.mark.parametrize("periods, Tr, phase", [(1, 2.0, 0.0), (3, 1.5, 0.0), (2, 3.0, 1.7)])
def test_starts_and_ends_exactly_at_rest_on_the_path(periods, Tr, phase):
    path = _path()
    m = RampedMotion(path, periods, Tr, phase)
    q, v, vd = m.evaluate(np.array([0.0, m.duration]))
    assert np.all(v == 0.0) and np.all(vd == 0.0)
    q_start, _, _ = path.evaluate(np.array([phase - Tr / 2]))
    q_end, _, _ = path.evaluate(np.array([phase + periods * path.period + Tr / 2]))
    np.testing.assert_allclose(q[0], q_start[0], atol=1e-12)
    np.testing.assert_allclose(q[1], q_end[0], atol=1e-12)
    # before and after: at rest at the same postures
    q2, v2, vd2 = m.evaluate(np.array([-1.0, m.duration + 1.0]))
    np.testing.assert_allclose(q2, q, atol=1e-12)
    assert np.all(v2 == 0.0) and np.all(vd2 == 0.0)
    assert m.duration == pytest.approx(2 * Tr + periods * path.period)


@pytest.mark.parametrize("phase", [0.0, 1.2])
def test_continuous_at_the_joins_and_periodic_part_is_the_path(phase):
    path = _path()
    m = RampedMotion(path, 2, 2.0, phase)
    eps = 1e-11
    for tj in (m.periodic_start, m.periodic_end):
        a = m.evaluate(np.array([tj - eps]))
        b = m.evaluate(np.array([tj + eps]))
        for x, y in zip(a, b):
            np.testing.assert_allclose(x, y, atol=1e-9)
    t = np.linspace(m.periodic_start, m.periodic_end, 101)
    for x, y in zip(m.evaluate(t), path.evaluate(t - m.periodic_start + phase)):
        np.testing.assert_allclose(x, y, atol=1e-12)


def test_v_and_vdot_are_the_time_derivatives_of_q():
    path = _path()
    m = RampedMotion(path, 1, 2.0, 0.4)
    t = np.linspace(0.01, m.duration - 0.01, 400)
    h = 1e-6
    qp, vp, _ = m.evaluate(t + h)
    qm, vm, _ = m.evaluate(t - h)
    _, v, vd = m.evaluate(t)
    np.testing.assert_allclose((qp - qm) / (2 * h), v, atol=1e-7)
    np.testing.assert_allclose((vp - vm) / (2 * h), vd, atol=1e-6)


def test_acceleration_bound_and_postures_on_the_path():
    path = _path()
    Tr = 2.0
    m = RampedMotion(path, 1, Tr)
    t = np.arange(0, Tr, 1e-3)
    q, v, vd = m.evaluate(t)
    s = m.timing(t)
    dq, ddq = path.evaluate(s.s)[1:]
    assert np.all(np.abs(s.s_ddot) <= 1.875 / Tr + 1e-12)
    assert np.all(np.abs(vd) <= np.abs(ddq) + np.abs(dq) * 1.875 / Tr + 1e-12)
    assert np.all(np.abs(v) <= np.abs(dq) + 1e-12)


def test_choose_ramp_duration_picks_the_shortest_that_holds_at_1khz():
    path = _path()
    limits = _limits(path)
    motion, checks = choose_ramp_duration(path, limits, durations=(0.2, 1.0, 3.0, 8.0, 20.0))
    assert checks[-1].ok and motion.ramp_duration == checks[-1].ramp_duration
    assert not checks[0].ok  # 0.2 s is too short for these limits: the check can fail
    m = ramp_margins(motion, limits)
    assert min(m.values()) >= -1e-6
    # the whole motion at 1 kHz, ramps and periods, within the limits
    t = motion.sample_times(1000.0)
    q, v, vd = motion.evaluate(t)
    assert np.all(np.abs(v) <= limits.v_max + 1e-9) and np.all(np.abs(vd) <= limits.vd_max + 1e-6)


def test_no_ramp_possible_is_refused_with_the_reason():
    path = _path()
    limits = _limits(path, factor=1.0)
    limits.v_max = limits.v_max * 0.5  # the path itself is too fast: no ramp helps
    with pytest.raises(InfeasibleError, match="velocity margin"):
        choose_ramp_duration(path, limits, durations=(1.0, 2.0))


def test_phase_candidates_start_with_zero():
    path = _path()
    phases = phase_candidates(path, _limits(path))
    assert phases[0] == 0.0 and len(phases) == 4 and all(0 <= p < path.period for p in phases)


def test_sample_times_cover_the_motion_on_a_uniform_grid():
    m = RampedMotion(_path(), 2, 1.2345)
    t = m.sample_times(1000.0)
    assert t[-1] >= m.duration - 1e-9 and t[-1] - m.duration < 1e-3
    np.testing.assert_allclose(np.diff(t), 1e-3)


@pytest.mark.parametrize("data, match", [
    ({"periods": 0}, "periods"), ({"periods": 1.5}, "periods"), ({"periods": "2"}, "periods"),
    ({"ramp_duration": -1}, "ramp_duration"), ({"ramp_duration": float("nan")}, "ramp_duration"),
    ({"ramp_duration": "x"}, "ramp_duration"), ({"phase": 100.0}, "phase"),
])
def test_bad_ramp_values_in_the_file_are_refused(data, match):
    with pytest.raises(ConfigError, match=match):
        ramped_motion_from_dict(_path(), data, source="t.json")


def test_old_files_are_one_period_without_ramps():
    m = ramped_motion_from_dict(_path(), {})
    assert m.periods == 1 and m.ramp_duration == 0.0
