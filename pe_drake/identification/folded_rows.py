"""Least squares on an hour-long run in bounded memory: each channel's regressor rows folded
into the R factor of their QR, block by block.

For the rows ``F_c`` and measurements ``y_c`` of channel ``c``, the R factor of ``[F_c | y_c]``
has the same Gram matrix, and every quantity of a least-squares fit is a function of that Gram
matrix (the solution, singular values, column norms, residual sums of squares, ``W_cᵀW_c``, the
physical fit's QR). So the fit runs on the folded rows ((channels · (k+1)) rows instead of
samples · channels), equal up to rounding, while the rows are built ``BLOCK`` samples at a time.
Only the residual's correlation time needs the residual series: :func:`residual_series`
rebuilds it block by block.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import NamedTuple

import numpy as np

#: Samples per block of rows built at once: (BLOCK, channels, columns) floats, a few MB.
BLOCK = 2000

#: ``blocks()`` yields (sample slice, F (s, r, k), y (s, r)) for consecutive slices.
RowBlocks = Callable[[], Iterator[tuple[slice, np.ndarray, np.ndarray]]]


class FoldedRows(NamedTuple):
    """The rows of every channel folded into the R factor of ``[F_c | y_c]``.

    Attributes:
        R: (r, k + 1, k + 1): per channel, upper triangular.
        samples: samples folded in (each gives one row per channel).
    """

    R: np.ndarray
    samples: int

    @property
    def channels(self) -> int:
        return self.R.shape[0]

    def stacked(self, T: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(A, y) with ``AᵀA``, ``Aᵀy`` and ``yᵀy`` those of the stacked rows ``[F_c T]`` and
        ``y_c`` of every channel, each channel scaled by ``weights[c]`` (default 1)."""
        r, k1, _ = self.R.shape
        w = np.ones(r) if weights is None else np.asarray(weights, float)
        A = np.concatenate([w[c] * self.R[c, :, : k1 - 1] @ T for c in range(r)])
        y = np.concatenate([w[c] * self.R[c, :, k1 - 1] for c in range(r)])
        return A, y

    def residual_ss(self, T: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Σ_samples (y_c − F_c T x)² per channel, shape (r,)."""
        k1 = self.R.shape[1]
        z = np.r_[T @ x, -1.0]
        return np.array([float(np.sum((Rc @ z) ** 2)) for Rc in self.R]) if k1 else np.zeros(self.channels)

    def measured_ss(self) -> np.ndarray:
        """Σ_samples y_c² per channel, shape (r,)."""
        return np.sum(self.R[:, :, -1] ** 2, axis=1)

    def channel_grams(self, T: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
        """(w_c F_c T)ᵀ (w_c F_c T) per channel, shape (r, p, p)."""
        r, k1, _ = self.R.shape
        w = np.ones(r) if weights is None else np.asarray(weights, float)
        A = [w[c] * self.R[c, :, : k1 - 1] @ T for c in range(r)]
        return np.array([a.T @ a for a in A])

    def with_known_columns(self, theta: np.ndarray) -> FoldedRows:
        """The rows with ``y_c − F_c θ`` as measurements (θ over the folded columns, (k,)):
        ``R_c M`` has the Gram matrix of ``[F_c | y_c] M`` (not triangular; nothing needs it)."""
        R = self.R.copy()
        R[:, :, -1] -= R[:, :, :-1] @ np.asarray(theta, float)
        return FoldedRows(R, self.samples)


def known_columns_removed(blocks: RowBlocks, theta: np.ndarray) -> RowBlocks:
    """``blocks`` with ``y − F θ`` as measurements (:meth:`FoldedRows.with_known_columns`)."""
    theta = np.asarray(theta, float)

    def shifted():
        for rows, F, y in blocks():
            yield rows, F, y - F @ theta

    return shifted


def fold_rows(blocks: RowBlocks) -> FoldedRows:
    """Folds every block of ``blocks()`` into the per-channel R factors."""
    R, samples = None, 0
    for _rows, F, y in blocks():
        s, r, k = F.shape
        if R is None:
            R = np.zeros((r, k + 1, k + 1))
        for c in range(r):
            stacked = np.vstack([R[c], np.column_stack([F[:, c, :], y[:, c]])])
            R[c] = np.linalg.qr(stacked, mode="r")  # k+1+s ≥ k+1 rows: always (k+1, k+1)
        samples += s
    if R is None:
        raise ValueError("no rows to fold")
    return FoldedRows(R, samples)


def residual_series(blocks: RowBlocks, samples: int, T: np.ndarray, x: np.ndarray,
                    weights: np.ndarray | None = None) -> np.ndarray:
    """The residual w_c (y_c − F_c T x) of every sample, (samples, r), rebuilt block by block."""
    theta = T @ x
    out = None
    for rows, F, y in blocks():
        if out is None:
            out = np.empty((samples, F.shape[1]))
        out[rows] = y - F @ theta
    if weights is not None:
        out *= np.asarray(weights, float)[None, :]
    return out


def column_map(total: int, columns) -> np.ndarray:
    """The (total, len(columns)) 0/1 matrix that picks ``columns`` of the folded columns."""
    columns = list(columns)
    T = np.zeros((total, len(columns)))
    T[columns, np.arange(len(columns))] = 1.0
    return T
