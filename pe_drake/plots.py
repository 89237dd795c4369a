"""Figures of an optimized trajectory and of a model's prediction, and the one way every
pe_drake figure is saved (:func:`save_figure`).

Figures are built on a matplotlib ``Figure`` with an Agg canvas (imported lazily), not through
pyplot, whose import costs half a figure's time; nothing here shows a window.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pe_drake.io_utils import atomic_write


def plot_trajectory(
    path: str | Path, robot, trajectory, singular_values: np.ndarray, title: str = "", note: str = ""
) -> Path:
    """q, v, vdot of every joint against its limits, and the singular-value spectrum of C.

    Args:
        trajectory: the :class:`~pe_drake.excitation.fourier.FourierTrajectory`.
        singular_values: σ of the stacked base regressor, descending.
        note: text printed in the singular-value panel (e.g. the quality figures).
    """
    t = np.linspace(0.0, trajectory.period, 1000)
    q, v, vd = trajectory.evaluate(t)
    lim = robot.limits
    # Fixed margins: the panels' extents are the same on every robot, so these are what
    # constrained layout computes for them, without its costly text measuring per figure.
    fig = _agg_figure(figsize=(13, 8.5))
    axes = fig.subplots(2, 2, gridspec_kw=_TRAJECTORY_MARGINS[bool(title)])
    for ax, x, lo, hi, label in (
        (axes[0, 0], (q - lim.q_lower) / (lim.q_upper - lim.q_lower) * 2 - 1, -1, 1, "position"),
        (axes[0, 1], v / lim.v_max, -1, 1, "velocity"),
        (axes[1, 0], vd / lim.vd_max, -1, 1, "acceleration"),
    ):
        for j, name in enumerate(robot.joint_names):
            ax.plot(t, x[:, j], lw=1, label=name)
        ax.axhline(lo, color="k", ls="--", lw=1)
        ax.axhline(hi, color="k", ls="--", lw=1)
        ax.set_title(f"{label} / limit (±1 = limit)")
        ax.set_xlabel("t [s]")
        ax.set_ylim(-1.15, 1.15)
    axes[0, 0].legend(fontsize=6, ncol=2, loc="lower right")
    ax = axes[1, 1]
    s = np.asarray(singular_values)
    ax.semilogy(np.arange(1, len(s) + 1), s, "o-", ms=3)
    ax.set_title(f"singular values of C (cond = {s[0] / s[-1]:.4g})")
    ax.set_xlabel("index")
    ax.grid(True, which="both", alpha=0.3)
    if note:
        ax.text(0.98, 0.98, note, transform=ax.transAxes, fontsize=7, va="top", ha="right",
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "0.8"})
    if title:
        fig.suptitle(title, y=0.995)  # where constrained layout put it: above the panel titles
    return save_figure(fig, path, dpi=90)


#: subplot parameters of :func:`plot_trajectory` with and without a title (suptitle room).
_TRAJECTORY_MARGINS = {
    True: {"left": 0.0368, "right": 0.9968, "bottom": 0.0561, "top": 0.9406, "wspace": 0.0952, "hspace": 0.2162},
    False: {"left": 0.0368, "right": 0.9968, "bottom": 0.0561, "top": 0.97, "wspace": 0.0952, "hspace": 0.2086},
}


def _agg_figure(**kwargs):
    """A matplotlib Figure drawn by Agg, without pyplot (nothing to close, no backend switch)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # lazy: matplotlib is heavy
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | Path, dpi: int = 80) -> Path:
    """Saves ``fig`` whole or not at all (:func:`~pe_drake.io_utils.atomic_write`), in the format
    of ``path``'s suffix (.png, .pdf, .svg), and closes it if pyplot made it."""
    fmt = Path(path).suffix.lower().lstrip(".") or "png"
    try:
        return atomic_write(path, lambda out: fig.savefig(out, dpi=dpi, format=fmt), binary=True,
                            suffix=f".tmp.{fmt}")
    finally:
        if getattr(fig.canvas, "manager", None) is not None:  # made by pyplot: release it there
            import matplotlib.pyplot as plt  # lazy: matplotlib is heavy

            plt.close(fig)


def envelope(t: np.ndarray, y: np.ndarray, bins: int = 5000) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) as drawn: a long series as the minimum and maximum of each of ``bins`` bins (the
    same picture at a figure's resolution, far fewer points); a short one unchanged."""
    if len(t) <= 4 * bins:
        return t, y
    edges = np.linspace(0, len(t), bins + 1).astype(int)
    lo, hi = np.minimum.reduceat(y, edges[:-1]), np.maximum.reduceat(y, edges[:-1])
    mid = t[(edges[:-1] + edges[1:]) // 2]
    return np.repeat(mid, 2), np.column_stack([lo, hi]).ravel()


def plot_prediction(path: str | Path, robot_name: str, t, measured, predicted, rel, names, title: str = "") -> Path:
    """Measured channels, a model's prediction and their difference, one panel per channel
    (``identify``'s residuals.png, ``validate --plot``)."""
    n = measured.shape[1]
    fig = _agg_figure(figsize=(11, 1.7 * n + 1), layout="constrained")
    axes = np.atleast_1d(fig.subplots(n, 1, sharex=True))
    for j, ax in enumerate(axes):
        ax.plot(*envelope(t, measured[:, j]), "k", lw=1, label="measured")
        ax.plot(*envelope(t, predicted[:, j]), "C1", lw=1, label="model")
        ax.plot(*envelope(t, measured[:, j] - predicted[:, j]), "C3", lw=0.7, alpha=0.7, label="error")
        unit = "N" if names[j].startswith("wrench.f") else "N·m"
        ax.set_ylabel(f"{names[j]}\n[{unit}]", fontsize=7)
        ax.set_title(f"relative error {rel[j]:.1f} %", fontsize=8, loc="right")
    axes[0].legend(fontsize=7, ncol=3, loc="upper left")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title or f"{robot_name}: measured vs predicted")
    return save_figure(fig, path)
