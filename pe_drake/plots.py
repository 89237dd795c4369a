"""Figures of an optimized trajectory (matplotlib, imported lazily, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_trajectory(
    path: str | Path, robot, trajectory, singular_values: np.ndarray, title: str = "", note: str = ""
) -> Path:
    """q, v, vdot of every joint against its limits, and the singular-value spectrum of C.

    Args:
        path: PNG file to write.
        robot: the :class:`~pe_drake.multibody.robot.Robot` (limits, joint names).
        trajectory: the :class:`~pe_drake.excitation.fourier.FourierTrajectory`.
        singular_values: σ of the stacked base regressor, descending.
        title: figure title.
        note: text printed in the singular-value panel (e.g. the quality figures).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.linspace(0.0, trajectory.period, 1000)
    q, v, vd = trajectory.evaluate(t)
    lim = robot.limits
    fig, axes = plt.subplots(2, 2, figsize=(13, 8.5), constrained_layout=True)
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
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
