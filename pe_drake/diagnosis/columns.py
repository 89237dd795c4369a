"""The columns of one segment of the diagnosis's regression, and their Gram matrices.

The base regressor and the timing nuisance act on every joint and are stored as (S, n, D);
the candidates act on one joint each and are kept as one series on their joint
(``overrides``), which saves memory on long logs.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence

import numpy as np

#: A segment whose stored columns would take more than this in float64 keeps them in float32;
#: its Gram matrices are summed in float64 before the rounding, so every fit is unchanged and
#: only residuals carry the ~1e-7 relative rounding.
LONG_LOG_BYTES = 512e6


@dataclasses.dataclass(frozen=True, eq=False)
class Columns:
    """Every column of one segment: base regressor, candidates, timing nuisance.

    Attributes:
        A: the stored columns, (S, n, D): those that act on every joint, in float32 for a long
            log (:data:`LONG_LOG_BYTES`).
        y: the target, the measured torque, (S, n).
        gram, rhs, yy: per-joint A_jᵀ A_j (n, P, P), A_jᵀ y_j (n, P), y_jᵀ y_j (n,).
        overrides: {column: (joint, values (S,))}: columns that act on one joint only (the
            candidates, a pre-sliding trial), zero on every other; they win over ``A``'s.
        stored: the column of each of A's, (D,); None: A holds every column in order.
    """

    A: np.ndarray
    y: np.ndarray
    gram: np.ndarray
    rhs: np.ndarray
    yy: np.ndarray
    count: int
    overrides: dict = dataclasses.field(default_factory=dict)
    stored: tuple[int, ...] | None = None

    @property
    def num_columns(self) -> int:
        """P, every column (stored or not)."""
        return self.gram.shape[1]

    @functools.cached_property
    def position(self) -> dict[int, int]:
        """{column: its index in A's last axis}."""
        stored = range(self.A.shape[2]) if self.stored is None else self.stored
        return {int(c): k for k, c in enumerate(stored)}

    def product(self, cols: Sequence[int], x: np.ndarray, chunk: int = 4000) -> np.ndarray:
        """The columns ``cols`` times ``x``, (S, n), a block of samples at a time (no (S, n, P) copy)."""
        cols, x = [int(c) for c in cols], np.asarray(x, float)
        plain = [k for k, c in enumerate(cols) if c not in self.overrides]
        idx = [self.position[cols[k]] for k in plain]
        out = np.zeros(self.y.shape)
        if plain:
            for s in range(0, self.count, chunk):
                rows = slice(s, min(s + chunk, self.count))
                out[rows] = self.A[rows][:, :, idx].astype(float) @ x[plain]
        for k, c in enumerate(cols):
            if c in self.overrides:
                joint, values = self.overrides[c]
                out[:, joint] += values * x[k]
        return out

    def joint_dot(self, joint: int, values: np.ndarray, chunk: int = 20000) -> np.ndarray:
        """valuesᵀ A[:, joint, :] with the overrides applied, (P,), without an (S, P) copy."""
        out = np.zeros(self.num_columns)
        stored = list(self.position)
        for s in range(0, self.count, chunk):
            rows = slice(s, min(s + chunk, self.count))
            out[stored] += values[rows] @ self.A[rows, joint, :].astype(float)
        for c, (j, series) in self.overrides.items():
            out[c] = series @ values if j == joint else 0.0
        return out

    def block(self, rows: slice) -> np.ndarray:
        """Every column of the samples ``rows`` with the overrides applied, (len, n, P), float64."""
        k = len(range(*rows.indices(self.count)))
        out = np.zeros((k, self.y.shape[1], self.num_columns))
        out[:, :, list(self.position)] = self.A[rows]
        for c, (j, values) in self.overrides.items():
            out[:, :, c] = 0.0
            out[:, j, c] = values[rows]
        return out

    def moments(self, rows: Sequence[slice], chunk: int = 4000) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(gram, rhs, yy, count) of some runs of samples, a block of samples at a time."""
        n, P = self.rhs.shape
        gram, rhs, yy, count = np.zeros((n, P, P)), np.zeros((n, P)), np.zeros(n), 0
        for run in rows:
            start, stop, _ = run.indices(self.count)
            for s in range(start, stop, chunk):
                part = slice(s, min(s + chunk, stop))
                A, y = self.block(part), self.y[part]
                gram += np.einsum("sjp,sjq->jpq", A, A, optimize=True)
                rhs += np.einsum("sjp,sj->jp", A, y, optimize=True)
                yy += np.einsum("sj,sj->j", y, y)
                count += A.shape[0]
        return gram, rhs, yy, count

    def joint_block(self, joint: int) -> np.ndarray:
        """A[:, joint, :] with the overrides applied, (S, P)."""
        block = np.zeros((self.count, self.num_columns))
        block[:, list(self.position)] = self.A[:, joint, :]
        for c, (j, values) in self.overrides.items():
            block[:, c] = values if j == joint else 0.0
        return block

    @classmethod
    def from_matrix(cls, A: np.ndarray, y: np.ndarray) -> Columns:
        """The columns A (S, n, P) against the torque y (S, n)."""
        gram = np.einsum("sjp,sjq->jpq", A, A, optimize=True)
        rhs = np.einsum("sjp,sj->jp", A, y, optimize=True)
        yy = np.einsum("sj,sj->j", y, y)
        return cls(A, y, gram, rhs, yy, y.shape[0])

    @classmethod
    def assemble(cls, y: np.ndarray, num_columns: int, stored: Sequence[int],
                 fill: Callable[[slice, np.ndarray], None], single: dict, chunk: int = 4000) -> Columns:
        """The P = ``num_columns`` columns of a segment built a block of samples at a time.

        Args:
            stored: the columns that act on every joint, kept in ``A``.
            fill: ``fill(rows, out)`` writes those columns of the samples ``rows`` into ``out``,
                (len(rows), n, len(stored)), float64.
            single: {column: (joint, values (S,))}, the columns that act on one joint.
        """
        S, n = y.shape
        stored = [int(c) for c in stored]
        dtype = np.float32 if S * n * len(stored) * 8 > LONG_LOG_BYTES else np.float64
        A = np.empty((S, n, len(stored)), dtype)
        gram, rhs = np.zeros((n, num_columns, num_columns)), np.zeros((n, num_columns))
        for s in range(0, S, chunk):
            rows = slice(s, min(s + chunk, S))
            part = np.empty((rows.stop - rows.start, n, len(stored)))
            fill(rows, part)
            A[rows] = part
            block = np.zeros((rows.stop - rows.start, n, num_columns))
            block[:, :, stored] = part
            for c, (j, values) in single.items():
                block[:, j, c] = values[rows]
            gram += np.einsum("sjp,sjq->jpq", block, block, optimize=True)
            rhs += np.einsum("sjp,sj->jp", block, y[rows], optimize=True)
        yy = np.einsum("sj,sj->j", y, y)
        return cls(A, y, gram, rhs, yy, S, dict(single), tuple(stored))
