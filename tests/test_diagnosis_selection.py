"""The diagnosis's selection on the training data alone (issue 23): the blocked
cross-validation of the training segment and the fits from its moments. The workflow-level
test (the held-out torques replaced, the selection unchanged) is in tests/test_diagnosis.py."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from pe_drake.diagnosis.presliding import replace_column
from pe_drake.diagnosis.regression import Columns, Regression
from pe_drake.diagnosis.selection import FOLDS, CrossValidation, Moments, internal_split, split_with_column
from pe_drake.exceptions import DataError


def _segment(duration: float, rate: float = 200.0, cutoff: float = 4.0):
    t = np.arange(0.0, duration, 1.0 / rate)
    return SimpleNamespace(t=t, num_samples=len(t), record=SimpleNamespace(cutoff_hz=cutoff, source="x.csv"))


def _rows(rows) -> np.ndarray:
    return np.concatenate([np.arange(s.start, s.stop) for s in rows])


def test_folds_keep_their_parts_apart_and_predict_every_sample_once():
    """Alternating blocks over the whole segment; in each fold the two parts are disjoint and
    1 / cut-off apart; over the folds every sample is predicted once."""
    seg = _segment(60.0)
    split = internal_split(seg)
    t = seg.t
    assert len(split.folds) == FOLDS == 3
    assert split.block_s == pytest.approx(2.5) and split.guard_s == pytest.approx(0.25)
    predicted = np.concatenate([_rows(f.selection_rows) for f in split.folds])
    np.testing.assert_array_equal(np.sort(predicted), np.arange(len(t)))
    for fold in split.folds:
        fit, sel = _rows(fold.fit_rows), _rows(fold.selection_rows)
        assert 7 <= len(fold.selection_rows) <= 8  # 23 blocks of 2.5 s, the last 5 ms joins the one before
        assert np.min(np.abs(t[fit][:, None] - t[sel][None, :])) > 0.25
        assert 0.55 < len(fit) / len(t) < 0.68
        assert t[sel].max() > 50.0 and t[sel].min() < 10.0


def test_a_short_training_segment_still_has_two_blocks_per_fold():
    split = internal_split(_segment(9.0))
    assert [len(f.selection_rows) for f in split.folds] == [2, 2, 2]
    assert split.block_s == pytest.approx(9.0 / 6, rel=0.01)
    with pytest.raises(DataError, match="x.csv"):
        internal_split(_segment(0.1))


def _direct(B, y, split, weights, b):
    """The cross-validated score from copies of the rows (the reference)."""
    folds = []
    for f in split.folds:
        fit, sel = _rows(f.fit_rows), _rows(f.selection_rows)
        r = Regression(Columns.from_matrix(B[fit], y[fit]), Columns.from_matrix(B[sel], y[sel]), b)
        r.set_weights(weights)
        folds.append(r)
    return CrossValidation(folds)


def test_cross_validation_from_moments_and_with_a_replaced_column():
    """The folds' moments are those of their rows; a replaced column (the pre-sliding step's
    Dahl column) gives the moments of the matrix with that column replaced, also on top of
    an earlier one."""
    rng = np.random.default_rng(1)
    S, n, P, b = 1200, 3, 6, 3
    A, y = rng.normal(size=(S, n, P)), rng.normal(size=(S, n))
    split = internal_split(_segment(S / 200.0))
    whole = Regression(Columns.from_matrix(A, y), Columns.from_matrix(A[:10], y[:10]), b)
    whole.set_weights(np.array([1.0, 2.0, 0.5]))
    cv = CrossValidation.of(whole, split)
    a, d = cv.fit([4, 5]), _direct(A, y, split, whole.weights, b).fit([4, 5])
    np.testing.assert_allclose(a.rms_held, d.rms_held, rtol=1e-8)
    assert a.wrss_held == pytest.approx(d.wrss_held, rel=1e-10)
    values = rng.normal(size=S)
    replaced = split_with_column(cv, whole.train, split, 4, 1, values)
    B = A.copy()
    B[:, :, 4] = 0.0
    B[:, 1, 4] = values
    np.testing.assert_allclose(replaced.fit([4, 5]).rms_held, _direct(B, y, split, whole.weights, b).fit([4, 5]).rms_held,
                               rtol=1e-8)
    values2 = rng.normal(size=S)
    twice = split_with_column(replaced, replace_column(whole.train, 4, 1, values), split, 5, 2, values2)
    B[:, :, 5] = 0.0
    B[:, 2, 5] = values2
    np.testing.assert_allclose(twice.fit([4, 5]).rms_held, _direct(B, y, split, whole.weights, b).fit([4, 5]).rms_held,
                               rtol=1e-8)
    # moments of columns kept as one series on their joint are those of the dense matrix
    rows = split.folds[0].fit_rows
    m = Moments.of_rows(replace_column(whole.train, 4, 1, values), rows)
    C = A.copy()
    C[:, :, 4] = 0.0
    C[:, 1, 4] = values
    dense = np.concatenate([C[r] for r in rows])
    np.testing.assert_allclose(m.gram, np.einsum("sjp,sjq->jpq", dense, dense), rtol=1e-10, atol=1e-9)


def test_guards_complete_the_folds():
    split = internal_split(_segment(30.0))
    for f in split.folds:
        parts = np.concatenate([_rows(f.fit_rows), _rows(f.selection_rows), _rows(f.guard_rows)])
        np.testing.assert_array_equal(np.sort(parts), np.arange(6000))
