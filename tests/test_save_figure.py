"""Figures are saved whole, in the format their suffix names, through a temporary file of an
unpredictable name (a symlink planted at the old fixed name ``.P.tmp.png`` is never followed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from pe_drake.plots import save_figure  # noqa: E402


def _figure():
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    return fig


def test_planted_symlink_at_the_old_temporary_name_is_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / ".plot.png.tmp.png").symlink_to(victim)
    save_figure(_figure(), tmp_path / "plot.png")
    assert victim.read_text() == "keep me"
    assert (tmp_path / "plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_format_follows_the_suffix_and_nothing_is_left_behind(tmp_path):
    save_figure(_figure(), tmp_path / "plot.pdf")
    save_figure(_figure(), tmp_path / "plot.svg")
    assert (tmp_path / "plot.pdf").read_bytes().startswith(b"%PDF")
    assert b"<svg" in (tmp_path / "plot.svg").read_bytes()[:400]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plot.pdf", "plot.svg"]


def _trajectory_figure(robot, title):
    """plot_trajectory's figure, captured before it is saved and closed."""
    import numpy as np

    import pe_drake.plots as plots
    from pe_drake.config import ExcitationConfig
    from pe_drake.excitation.problem import ExcitationProblem

    problem = ExcitationProblem(robot, ExcitationConfig())
    alpha = problem.initial_guess(seed=0)
    captured = []
    original = plots.save_figure
    plots.save_figure = lambda fig, path, dpi=80: captured.append(fig) or path
    try:
        plots.plot_trajectory("unused.png", robot, problem.trajectory(alpha),
                              np.logspace(3, -1, problem.base.count), title=title, note="cond 1\nline 2")
    finally:
        plots.save_figure = original
    return captured[0]


def test_trajectory_figure_fixed_layout_keeps_every_label_inside_and_apart(panda):
    """The fixed margins that replaced constrained layout (issue 38): each panel with its
    ticks, labels and title inside the figure, no two panels overlapping, the title above them."""
    for title in ("panda: cond 232.5", ""):
        fig = _trajectory_figure(panda, title)
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        page = fig.bbox
        boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
        for box in boxes:
            assert page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
        for i, a in enumerate(boxes):
            for b in boxes[i + 1:]:
                assert not a.overlaps(b)
        if title:
            top = fig._suptitle.get_window_extent(renderer)
            assert top.y1 <= page.y1 and all(top.y0 >= box.y1 for box in boxes)


def test_trajectory_figure_does_not_import_pyplot(tmp_path):
    """plot_trajectory draws on an Agg Figure: pyplot's import (0.4 CPU-s) is not paid."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from pe_drake.multibody.robot import load_robot\n"
        "from pe_drake.config import ExcitationConfig\n"
        "from pe_drake.excitation.problem import ExcitationProblem\n"
        "from pe_drake.plots import plot_trajectory\n"
        "robot = load_robot('ur5')\n"
        "problem = ExcitationProblem(robot, ExcitationConfig())\n"
        f"plot_trajectory({str(tmp_path / 't.png')!r}, robot, problem.trajectory(problem.initial_guess(seed=0)),"
        " np.logspace(2, 0, problem.base.count), title='ur5')\n"
        "print('matplotlib.pyplot' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.strip().splitlines()[-1] == "False"
    assert (tmp_path / "t.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
